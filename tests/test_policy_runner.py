"""docs/reference/policy-file.md is complete: a runner written from it alone (examples/policy_runner.py, plain numpy)
gives the coverage `ennc-ql eval` gives on the same policy file, trials and seed, and breaking one documented rule does
not.

Seven small policies cover both decision modes and every frame of the moves: ENNC-QL option 2 on the shared8d state
(collab6d's six numbers and the two shared flags; per-robot tables, a `scale`, `fixed` shared clock, compass moves),
VQQL local (local2d, one table, no `scale`, `until_change` per-robot clocks), and the default formulation of `ennc-ql
up`, frame-recall-track (each robot remembers the targets it lost from step to step, and names its moves in the law
frame: the pull of the force law on the state's information, the remembered target included, or where the law pulls
nowhere its search heading, which the law's last pull set; deciding every step); frame-guided (the frame9d state, the
relative moves in the target frame) and frame-recall (remembering, relative moves) cover the target frame,
frame-recall-law the law frame that falls back to the target frame where the law pulls nowhere, frame-recall-search
the search heading that only the wall turns. An eighth file is the default's policy with 5 added to every value of
the move `back` and a `law_margin` that no value beats: its argmax runs from every target, and read with the margin
it follows the law, so a runner that skipped the margin would miss by tens of points.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from algorithm.experiments import METHODS, train
from algorithm.policy_file import load_policy, save_policy
from ennc_ql.cli import main
from sim import scenario
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS
from tests.fakes import TINY as TINY_REPRODUCE

RUNNER = Path(__file__).resolve().parents[1] / "examples" / "policy_runner.py"
TRIALS, STEPS, SEED = 20, 1000, 0
# reproduce's test budget (a second or three of learning: poor policies, but policies the project wrote), with
# the learning process's own test trials cut short: this test evaluates the policy itself.
TINY = dataclasses.replace(TINY_REPRODUCE, test_trials=1, test_steps=10)


OPTION2 = METHODS["ennc-ql-collab-option2"]
SPECS = {
    "shared8d": (OPTION2, OPTION2.formulation.replace(featurizer="shared8d", reward="difference")),
    "vqql-local-16": (METHODS["vqql-local-16"], None),
    DEFAULT_FORMULATION: (OPTION2, FORMULATIONS[DEFAULT_FORMULATION]),
    "frame-guided": (OPTION2, FORMULATIONS["frame-guided"]),
    "frame-recall": (OPTION2, FORMULATIONS["frame-recall"]),
    "frame-recall-search": (OPTION2, FORMULATIONS["frame-recall-search"]),
    "frame-recall-law": (OPTION2, FORMULATIONS["frame-recall-law"]),
}
MARGINS = {f"{DEFAULT_FORMULATION}, law margin": (DEFAULT_FORMULATION, 1e6)}
"""A policy of SPECS saved again with its move ``back`` favoured and a law margin."""


_LEARNED: dict[str, Path] = {}


def learned(name: str, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """SPECS[name]'s policy file, learned once per module."""
    if name in _LEARNED:
        return _LEARNED[name]
    if name in MARGINS:
        of, margin = MARGINS[name]
        policy, _ = load_policy(learned(of, tmp_path_factory))
        back = policy.formulation.actions.moves.index("back")
        tables = policy.tables.copy()
        tables[:, policy.discretization.offsets[back] : policy.discretization.offsets[back + 1]] += 5.0
        changed = dataclasses.replace(policy, tables=tables, law_margin=margin)
        _LEARNED[name] = save_policy(changed, scenario(), tmp_path_factory.mktemp("policy") / "margin.npz")
        return _LEARNED[name]
    spec, formulation = SPECS[name]
    outcome = train(spec, TINY, seed=0, formulation=formulation)
    assert outcome.policy is not None and outcome.policy.formulation == (formulation or spec.formulation)
    _LEARNED[name] = save_policy(outcome.policy, scenario(), tmp_path_factory.mktemp("policy") / f"{name}.npz")
    return _LEARNED[name]


@pytest.fixture(scope="module", params=[*SPECS, *MARGINS])
def policy_file(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return learned(request.param, tmp_path_factory)


# The search rules broken below are the same under every state; the remembering tiny policies spread too widely
# between trials for 20 of them to separate a broken rule by 3 SE.
@pytest.fixture(scope="module", params=[name for name in SPECS if not name.startswith("frame-recall")])
def searching_policy_file(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return learned(request.param, tmp_path_factory)


def project_coverage(path: Path, capsys: pytest.CaptureFixture[str]) -> np.ndarray:
    """Per-trial coverage from the project's own `ennc-ql eval --policy PATH --json`."""
    capsys.readouterr()
    args = ["eval", "--policy", str(path), "--trials", str(TRIALS), "--steps", str(STEPS), "--seed", str(SEED)]
    assert main([*args, "--json"]) == 0
    return np.asarray(json.loads(capsys.readouterr().out)["coverage_per_trial"])


def runner_coverage(path: Path, *extra: str) -> np.ndarray:
    """Per-trial coverage from the reference runner, run as a separate program (it imports nothing of the project)."""
    args = [str(path), "--trials", str(TRIALS), "--steps", str(STEPS), "--seed", str(SEED), "--json", *extra]
    done = subprocess.run([sys.executable, str(RUNNER), *args], capture_output=True, text=True, timeout=120, check=True)
    return np.asarray(json.loads(done.stdout)["coverage_per_trial"])


def tolerance(a: np.ndarray, b: np.ndarray) -> float:
    """Three standard errors of the difference of the two means.

    The runner does not promise the project's random streams, so the two runs are treated as independent samples
    of TRIALS trials each: SE(mean_a − mean_b) = sqrt(s_a²/N + s_b²/N) with the sample standard deviations. Two
    correct simulators then differ by more than 3 SE with probability ≈ 0.3%; a run that shares the streams (as the
    runner does: its trials start step for step as the project's, then may drift by float rounding,
    docs/reference/policy-file.md; 0.1 point in the mean of 20 trials on make run's policy, 2026-12-04) only makes the
    check easier to pass. One point is the floor, so that near-identical per-trial figures cannot make the bound
    vanish.
    """
    se = float(np.sqrt(a.var(ddof=1) / a.size + b.var(ddof=1) / b.size))
    return max(3.0 * se, 1.0)


def test_runner_reproduces_ennc_ql_eval(policy_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    project = project_coverage(policy_file, capsys)
    runner = runner_coverage(policy_file)
    assert runner.shape == project.shape == (TRIALS,)
    gap, bound = abs(runner.mean() - project.mean()), tolerance(runner, project)
    assert gap <= bound, f"runner {runner.mean():.2f}% vs project {project.mean():.2f}% (bound {bound:.2f})"


@pytest.mark.parametrize("violation", ["still-start", "no-reflect"])
def test_breaking_a_documented_rule_shows(
    searching_policy_file: Path, violation: str, capsys: pytest.CaptureFixture[str]
) -> None:
    policy_file = searching_policy_file
    # Robots without a search heading (standing still while lost) or whose heading is never reflected off the wall
    # must observe clearly fewer targets: the same 3-SE bound, one-sided, must separate them from the project.
    project = project_coverage(policy_file, capsys)
    broken = runner_coverage(policy_file, "--violate", violation)
    bound = tolerance(broken, project)
    assert broken.mean() < project.mean() - bound, (
        f"--violate {violation}: {broken.mean():.2f}% vs project {project.mean():.2f}% (bound {bound:.2f})"
    )
