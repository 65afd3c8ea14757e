"""``ennc-ql bench actor``: an actor's phase-2 slice against the bare simulator (figures only, no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.policy_file import save_policy
from ennc_ql.cli import main
from sim import Formulation, scenario


@pytest.fixture(params=[("collab6d", "eq2", 6), ("shared8d", "difference", 8)], ids=["paper", "shared-difference"])
def policy_file(tmp_path: Path, request: pytest.FixtureRequest) -> Path:
    """A policy of each formulation: the slice acts and learns in the state the policy was learned in."""
    featurizer, reward, dim = request.param
    cfg = scenario()
    rng = np.random.default_rng(0)
    disc = Discretization.from_per_action([rng.uniform(-150, 150, (size, dim)) for size in (3, 5, 2, 7, 1, 4, 6, 2)])
    tables = np.zeros((cfg.n_robots, disc.size), np.float32)
    policy = Policy(Formulation.of(featurizer, reward, "compass"), disc, tables, np.arange(cfg.n_robots))
    return save_policy(policy, cfg, tmp_path / "policy.npz")


def test_bench_actor_reports_the_slice_against_the_simulator(
    capsys: pytest.CaptureFixture[str], policy_file: Path
) -> None:
    argv = ["bench", "actor", "--policy", str(policy_file), "--arenas", "4", "--seconds", "0.01", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert {"robot_steps_per_s", "sim_robot_steps_per_s", "ratio", "tuples_per_s", "prototypes_per_action"} <= set(out)
    assert out["prototypes_per_action"] == [3, 5, 2, 7, 1, 4, 6, 2]
    assert out["robot_steps_per_s"] > 0 and out["sim_robot_steps_per_s"] > 0 and out["tuples_per_s"] > 0
    assert out["ratio"] == pytest.approx(out["robot_steps_per_s"] / out["sim_robot_steps_per_s"], rel=1e-3, abs=1e-4)
    assert out["arenas"] == 4


def test_bench_actor_prints_a_table_without_json(capsys: pytest.CaptureFixture[str], policy_file: Path) -> None:
    assert main(["bench", "actor", "--policy", str(policy_file), "--arenas", "2", "--seconds", "0.01"]) == 0
    text = capsys.readouterr().out
    assert "robot-steps/s" in text and "ratio" in text


def _frame_policy(tmp_path: Path, featurizer: str = "frame9d", actions: str = "relative") -> Path:
    cfg = scenario()
    rng = np.random.default_rng(0)
    formulation = Formulation.of(featurizer, "difference-redundancy", actions)
    disc = Discretization.from_per_action(
        [rng.uniform(-1, 1, (size, formulation.dim)) for size in (3, 5, 2, 7, 1, 4, 6, 2)]
    )
    tables = np.zeros((cfg.n_robots, disc.size), np.float32)
    policy = Policy(formulation, disc, tables, np.arange(10))
    return save_policy(policy, cfg, tmp_path / "policy.npz")


@pytest.mark.parametrize(
    ("parts", "flags", "rules"),
    [
        (("frame11d-recall", "law-track"), (), "guided-search"),
        (("frame9d", "relative"), (), "paper"),
        (("frame9d", "relative"), ("--formulation", "frame-cooperative"), "lost-searches"),
    ],
    ids=["run-default", "other-parts", "named"],
)
def test_bench_actor_runs_the_policy_under_the_trial_rules_an_actor_would(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    parts: tuple[str, str],
    flags: tuple[str, ...],
    rules: str,
) -> None:
    # A policy file carries no trial rules; an actor of the default formulation learns with the guide, and a policy
    # of other parts runs under its own formulation's (the paper's rules, unless named).
    argv = ["bench", "actor", "--policy", str(_frame_policy(tmp_path, *parts)), "--arenas", "2", "--seconds", "0.01"]
    assert main([*argv, *flags, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["trial_rules"] == rules


def test_bench_actor_refuses_a_formulation_over_other_parts(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    argv = ["bench", "actor", "--policy", str(_frame_policy(tmp_path)), "--formulation", "paper", "--arenas", "2"]
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code != 0
    assert "are not the policy's" in capsys.readouterr().err
