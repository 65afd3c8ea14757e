"""``ennc-ql up --rerun save``: learner and actors log into one recording, merged from their part files."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

from monitor import paths, summarize_recording
from tests.e2e import ACTOR_PACE, ennc_ql
from tests.monitor.rrd import rows


@pytest.mark.slow
def test_up_saves_one_recording_of_every_process(tmp_path: Path) -> None:
    recording = tmp_path / "watch.rrd"
    argv = ennc_ql(
        "up",
        "--duration=25",
        "--actor-arenas=32",
        f"--actor-max-tuples-per-s={ACTOR_PACE}",
        "--learner-min-tuples=20000",
        "--learner-phase1-max-patterns=400",
        "--learner-phase1-seed-prototypes=32",  # the default 512 seeds take the first fit 10-16 s on loaded cores
        "--learner-phase1-max-iterations=1",
        "--learner-eval-interval=5",
        f"--runs={tmp_path}",
        "--run-id=rec",
        "--json",
        "--rerun",
        "save",
        str(recording),
    )
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["recording"]["path"] == str(recording)
    assert not (tmp_path / "rec" / "rerun").exists()  # the part files went into the merged recording

    summary = summarize_recording(recording)
    assert summary["recording_ids"] == ["rec"]  # one recording: the run id, shared by every process
    entities = set(summary["entity_paths"])
    actors = {e.split("/")[1] for e in entities if e.startswith(paths.ACTORS + "/")}
    assert actors == {"actor-0", "actor-1"}
    for actor in actors:
        assert f"{paths.actor_arena(actor)}/targets" in entities
        assert rows(recording, paths.actor(actor, paths.ACTOR_COVERAGE), "Scalars:scalars", paths.SIM_STEP)
    # The evaluations of the learner (the learning curve), and the final figure of the report as its own marker.
    # Every point of the report's curve is in the recording, in order (how many fit in 25 s depends on the cores).
    evaluations = rows(recording, paths.LEARNER_COVERAGE_EVAL, "Scalars:scalars", paths.POLICY_VERSION)
    curve = [coverage for _, coverage in report["coverage_curve"]]
    assert len(evaluations) == len(curve) >= 1
    assert [value[0] for _, value in evaluations] == pytest.approx(curve, abs=1e-3)
    final = rows(recording, paths.LEARNER_COVERAGE_FINAL, "Scalars:scalars", paths.POLICY_VERSION)
    assert len(final) == 1 and abs(final[-1][1][0] - report["final_coverage_mean"]) < 1e-3
    prototypes = [paths.prototypes_of(k) for k in range(len(report["prototypes_per_action"]))]
    assert set(prototypes) <= entities
    logged = sum(len(rows(recording, p, "Points2D:positions", paths.POLICY_VERSION)[-1][1]) for p in prototypes)
    assert logged == sum(report["prototypes_per_action"])  # every prototype of the final discretization is drawn
