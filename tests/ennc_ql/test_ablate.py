"""``ennc-ql ablate``: settings by dotted path, the swept product of variants, and a tiny real sweep whose saved
policies carry the overrides and whose rows are scored, with the hand-made references, on the same seeded trials."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from algorithm.experiments import Budget
from algorithm.phase1 import Phase1Config
from algorithm.policy import PolicyController
from algorithm.policy_file import load_policy
from algorithm.selection import choose_margin
from ennc_ql.cli import main
from sim import CONTROLLERS, evaluate, scenario
from tools.config import ConfigError
from tools.sweeps.ablate import REFERENCES, Setup, ablate, parse_sets, variants


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--set", "budget.phase2.alfa=0.1"], "unknown key 'budget.phase2.alfa' (did you mean 'budget.phase2.alpha'?)"),
        (["--set", "budget.phase2.alpha"], "expected KEY=VALUE[,VALUE...]"),
        (["--set", "scenario.action_steps=x"], "scenario.action_steps: expected an integer, got 'x'"),
        (["--set", "budget.phase2.alpha=2"], "budget.phase2.alpha: alpha must lie in (0, 1], got 2.0"),
        (["--set", "lost_behaviour=fly"], "invalid choice: 'fly'"),
        (["--set", "scenario.action_steps=3", "--set", "scenario.action_steps=5"], "given twice"),
        (["--set", "featurizer=pixels"], "unknown featurizer 'pixels'; known: local2d, collab6d, shared8d"),
        (["--set", "reward=money"], "unknown reward 'money'; known: paper, observed, eq2, difference"),
        (["--set", "trial_rules=lenient"], "unknown trial rules 'lenient'; known: paper, search-on"),
        (["--set", "budget.law_margin_trials=-1"], "budget.law_margin_trials: law_margin_trials must be >= 0"),
    ],
)
def test_bad_settings_are_one_line_errors(
    flags: list[str], message: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["ablate", "ennc-ql-collab-option2", *flags, "--out", str(tmp_path / "a")])
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ennc-ql ablate: error:") and message in lines[0]
    assert not (tmp_path / "a").exists()


def test_the_sweep_is_the_product_of_the_values_applied_by_path() -> None:
    sweep = parse_sets(["budget.phase2.alpha=0.05,0.2", "scenario.action_steps=3,5,10", "lost_behaviour=stay"])
    assert sweep == [
        ("budget.phase2.alpha", [0.05, 0.2]),
        ("scenario.action_steps", [3, 5, 10]),
        ("lost_behaviour", ["stay"]),
    ]
    out = variants(Setup(), sweep)
    assert len(out) == 6
    assert [(o["budget.phase2.alpha"], o["scenario.action_steps"]) for o, _ in out] == [
        (0.05, 3),
        (0.05, 5),
        (0.05, 10),
        (0.2, 3),
        (0.2, 5),
        (0.2, 10),
    ]
    for overrides, setup in out:
        assert setup.budget.phase2.alpha == overrides["budget.phase2.alpha"]
        assert setup.scenario.action_steps == overrides["scenario.action_steps"]
        assert setup.lost_behaviour == "stay"
        assert setup.budget.phase2.gamma == Setup().budget.phase2.gamma  # untouched fields keep their defaults
    assert variants(Setup(), []) == [({}, Setup())]
    with pytest.raises(ConfigError, match="unknown method"):
        ablate("ennc-ql-nonsense", [], Setup(), 1, Path("unused"))


def tiny(test_trials: int) -> Budget:
    """A sweep's process in about a second: 6 arenas, one batch of each phase, tested on ``test_trials`` of 60 steps."""
    return Budget(
        arenas=6,
        explore_trials=1,
        phase2_trials=1,
        phase1=Phase1Config(max_iterations=1, max_patterns=1500, n_cycles=5),
        test_trials=test_trials,
        test_steps=60,
        law_margin_trials=2,
    )


def test_a_tiny_sweep_scores_every_variant_on_the_same_trials_and_saves_the_overrides(tmp_path: Path) -> None:
    budget = tiny(test_trials=2)
    sweep = parse_sets(
        ["lost_behaviour=wander,stay", "scenario.action_steps=3", "featurizer=shared8d", "reward=difference"]
    )
    report = ablate("ennc-ql-collab-option2", sweep, Setup(budget=budget), processes=2, out_dir=tmp_path)
    rows = report["variants"]
    assert [r["label"] for r in rows] == [
        "lost_behaviour=wander, scenario.action_steps=3, featurizer=shared8d, reward=difference",
        "lost_behaviour=stay, scenario.action_steps=3, featurizer=shared8d, reward=difference",
    ]
    cfg = scenario(action_steps=3)
    references = {name: evaluate(cfg, CONTROLLERS[name], 2, 60, seed=0).coverage_mean for name in REFERENCES}
    for row in rows:
        assert len(row["coverage_per_run"]) == 2
        assert row["coverage_mean"] == pytest.approx(np.mean(row["coverage_per_run"]), abs=1e-3)
        assert row["references"] == pytest.approx(references, abs=1e-3)
    for variant, behaviour in ((1, "wander"), (2, "stay")):
        for seed in (0, 1):
            policy = load_policy(tmp_path / "policies" / f"v{variant}-{seed}.npz")[0]
            assert (policy.action_steps, policy.lost_behaviour) == (3, behaviour)
            assert (*policy.formulation.names[:2], policy.discretization.dim) == ("shared8d", "difference", 8)
    # The test-time rule changes no learning: the same seed learns the same tables in both variants.
    for seed in (0, 1):
        a = load_policy(tmp_path / "policies" / f"v1-{seed}.npz")[0]
        b = load_policy(tmp_path / "policies" / f"v2-{seed}.npz")[0]
        np.testing.assert_array_equal(a.tables, b.tables)
    assert json.loads((tmp_path / "results.json").read_text())["variants"] == rows
    table = (tmp_path / "results.md").read_text().splitlines()
    assert len([line for line in table if line.startswith("| lost_behaviour=")]) == 2
    assert (tmp_path / "ablation.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_neural_reference_is_scored_beside_without_a_policy_file(tmp_path: Path) -> None:
    from algorithm.fqi import FQIConfig

    budget = Budget(
        arenas=6,
        explore_trials=1,
        phase2_trials=2,
        fqi=FQIConfig(hidden=8, iterations=2, round_iterations=1, steps=5, rounds=2),
        test_trials=2,
        test_steps=60,
    )
    sweep = parse_sets(["featurizer=frame9d", "actions=relative", "reward=difference-decision"])
    report = ablate("fqi-mlp", sweep, Setup(budget=budget), processes=1, out_dir=tmp_path)
    (row,) = report["variants"]
    assert len(row["coverage_per_run"]) == 1 and 0.0 <= row["coverage_mean"] <= 100.0
    honest = evaluate(scenario(), CONTROLLERS["a-cmommt"], 2, 60).coverage_mean
    assert row["references"]["a-cmommt"] == pytest.approx(honest, abs=1e-3)
    assert report["paper_coverage"] is None
    assert not (tmp_path / "policies").exists()  # the network is a reference, not a policy file


def test_rows_carry_the_paired_difference_and_the_law_margin_each_process_chose(tmp_path: Path) -> None:
    """A law-track variant read by its argmax and the same processes read with a margin chosen on validation trials:
    the same tables, the margins the processes saved, and every reference's paired difference per trial, recomputed
    here from the saved policies on the same trials."""
    budget = tiny(test_trials=3)
    sweep = parse_sets(["budget.law_margin_trials=0,2", "actions=law-track", "reward=difference"])
    report = ablate("ennc-ql-collab-option2", sweep, Setup(budget=budget), processes=2, out_dir=tmp_path)
    cfg = scenario()
    references = {name: evaluate(cfg, CONTROLLERS[name], 3, 60, seed=0).coverage_per_trial for name in REFERENCES}
    for variant, row in enumerate(report["variants"], start=1):
        policies = [load_policy(tmp_path / "policies" / f"v{variant}-{seed}.npz")[0] for seed in (0, 1)]
        assert row["law_margin_per_run"] == [p.law_margin for p in policies]
        team = np.mean([evaluate(cfg, PolicyController(p), 3, 60, seed=0).coverage_per_trial for p in policies], axis=0)
        for name, ref in references.items():
            diff = team - ref
            mean, se = row["paired"][name]
            assert mean == pytest.approx(diff.mean(), abs=1e-3)
            assert se == pytest.approx(diff.std(ddof=1) / np.sqrt(3), abs=1e-3)
        line = next(line for line in (tmp_path / "results.md").read_text().splitlines() if row["label"] in line)
        assert f"{row['paired']['a-cmommt'][0]:+.2f} ± {row['paired']['a-cmommt'][1]:.2f}" in line
    assert report["variants"][0]["law_margin_per_run"] == [0.0, 0.0]
    for seed in (0, 1):  # what choose_margin picks on the 2 validation trials (0.3 and 0.2 here), as the learner would
        policy = load_policy(tmp_path / "policies" / f"v2-{seed}.npz")[0]
        argmax = dataclasses.replace(policy, law_margin=0.0)
        assert policy.law_margin == choose_margin(cfg, argmax, 2, 60).margin
    for seed in (0, 1):  # the margin reads the tables; it changes no learning
        a = load_policy(tmp_path / "policies" / f"v1-{seed}.npz")[0]
        b = load_policy(tmp_path / "policies" / f"v2-{seed}.npz")[0]
        np.testing.assert_array_equal(a.tables, b.tables)
