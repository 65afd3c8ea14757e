"""``ennc-ql up --serial``: the learner and the actors as objects in one process, with the same report."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest

from algorithm.selection import DEVELOPMENT_SEED, TEST_SEED
from ennc_ql.cli import main
from sim import CONTROLLERS, evaluate, scenario

SMALL = [
    "--actors=2",
    "--duration=20",
    "--actor-arenas=16",
    "--actor-batch-size=512",
    "--actor-flush-timeout=5",
    "--learner-min-tuples=6000",
    "--learner-phase1-max-patterns=300",
    "--learner-phase1-n-cycles=10",
    "--learner-phase1-seed-prototypes=32",  # the default 512 seeds take the first fit 10-16 s on loaded cores
    "--learner-phase1-max-iterations=1",
    "--learner-broadcast-interval=1",
    "--learner-checkpoint-interval=1",
    "--learner-eval-interval=5",
    "--learner-eval-trials=1",
    "--learner-eval-steps=100",
    "--learner-final-eval-trials=2",
]


@pytest.mark.slow
def test_serial_run_learns_and_reports_like_the_process_topology(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    before = threading.active_count()
    assert main(["up", "--serial", *SMALL, f"--runs={tmp_path}", "--run-id=serial", "--json"]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    run_dir = tmp_path / "serial"
    assert report["actors"] == ["actor-0", "actor-1"]
    assert report["tuples_received"] == sum(report["tuples_by_actor"].values()) > 6000
    assert report["policy_version"] >= 1 and report["phase1_fits"] == 1
    assert report["duplicates"] == 0 and report["gaps"] == 0 and report["rejected"] == 0
    assert 0.0 < report["final_coverage_mean"] <= 100.0 and report["final_eval_trials"] == 2
    assert report["config"]["serial"] is True and report["command"] == f"ennc-ql up --config {run_dir / 'up.toml'}"
    for name in ("up.toml", "learner.toml", "actor-0.toml", "actor-1.toml", "policy.npz", "report.md", "policy.png"):
        assert (run_dir / name).exists(), name
    assert json.loads((run_dir / "report.json").read_text())["tuples_received"] == report["tuples_received"]
    # The result is read beside the hand-made controllers on the same trials, measured by the learner in this run,
    # and report.md says so first: the final figure on the reported test trials, the curve on development ones.
    references = report["final_reference_coverage"]
    assert set(references) == set(CONTROLLERS) and {"a-cmommt", "a-cmommt-public", "a-cmommt-oracle"} <= set(references)
    for name in ("a-cmommt", "a-cmommt-oracle"):
        expected = evaluate(scenario(), CONTROLLERS[name], trials=2, steps=100, seed=TEST_SEED).coverage_mean
        assert references[name] == pytest.approx(expected, abs=1e-3)
        assert report["reference_coverage"][name] == pytest.approx(
            evaluate(scenario(), CONTROLLERS[name], trials=1, steps=100, seed=DEVELOPMENT_SEED).coverage_mean, abs=1e-3
        )
    markdown = (run_dir / "report.md").read_text().splitlines()
    assert markdown[2] == "## Result"
    assert (
        "| A-CMOMMT oracle (true positions) | oracle, not a rival: reads true target positions that no robot senses | "
        in ("\n".join(markdown))
    )
    assert threading.active_count() == before  # every actor thread and transport worker ended
