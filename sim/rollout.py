"""Seeded test trials: run a controller on a batch of arenas and measure metric A.

Usage::

    from sim.config import scenario
    from sim.controllers import HAND_MADE
    result = evaluate(scenario(), HAND_MADE["a-cmommt"], trials=10, steps=1000, seed=0)
    result.coverage_mean   # % of targets under observation, averaged over trials
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.config import ScenarioConfig
from sim.controllers import Controller
from sim.features import coverage
from sim.world import Observation, WorldState, reset, sense, step

StepHook = Callable[[WorldState, Observation], None]


@dataclass(frozen=True, slots=True)
class Cooperation:
    """How a team spreads over the targets, per robot-step, summed over trials: why one policy covers more.

    A robot that sees only targets a teammate also sees adds nothing to metric A where it stands; one that sees no
    target is searching. A team that doubles up has many robots per covered target.
    """

    robot_steps: np.ndarray
    """(E,) robot-steps of each trial."""
    only_shared: np.ndarray
    """(E,) robot-steps in which every target the robot sees is seen by another robot too (and it sees one)."""
    none_in_view: np.ndarray
    """(E,) robot-steps in which the robot sees no target."""
    sightings: np.ndarray
    """(E,) Σ_t Σ_ij b_ij(t): robot-target pairs in view."""
    covered: np.ndarray
    """(E,) Σ_t Σ_j g(B(t), j): targets observed by at least one robot."""

    @classmethod
    def zeros(cls, trials: int) -> Cooperation:
        return cls(*(np.zeros(trials) for _ in range(5)))

    def add(self, obs: Observation) -> Cooperation:
        seen = obs.n_seen
        return Cooperation(
            robot_steps=self.robot_steps + seen.shape[1],
            only_shared=self.only_shared + ((seen > 0) & (obs.n_only == 0)).sum(axis=1),
            none_in_view=self.none_in_view + (seen == 0).sum(axis=1),
            sightings=self.sightings + seen.sum(axis=1),
            covered=self.covered + obs.covered,
        )

    def summary(self) -> dict[str, float]:
        """The three figures over every trial: shares of robot-steps (%) and robots per covered target."""
        steps = max(float(self.robot_steps.sum()), 1.0)
        return {
            "only_shared_pct": 100.0 * float(self.only_shared.sum()) / steps,
            "none_in_view_pct": 100.0 * float(self.none_in_view.sum()) / steps,
            "robots_per_covered_target": float(self.sightings.sum()) / max(float(self.covered.sum()), 1.0),
        }


@dataclass(frozen=True, slots=True)
class EvalResult:
    """Metric A of each trial, in percent of targets observed, and how the team spread over the targets."""

    coverage_per_trial: np.ndarray
    cooperation: Cooperation | None = None

    @property
    def coverage_mean(self) -> float:
        return float(self.coverage_per_trial.mean())

    @property
    def coverage_std(self) -> float:
        return float(self.coverage_per_trial.std())

    @property
    def robots_per_covered_target(self) -> float:
        """How thickly the team covered the targets it covered (NaN where the spread was not recorded)."""
        return float("nan") if self.cooperation is None else self.cooperation.summary()["robots_per_covered_target"]

    def minus(self, other: EvalResult) -> tuple[float, float]:
        """The paired difference of metric A, this policy minus ``other`` scored on the same trials: its mean over
        the trials and that mean's standard error (NaN with one trial)."""
        if other.coverage_per_trial.shape != self.coverage_per_trial.shape:
            raise ValueError("a paired difference needs the same trials")
        diff = self.coverage_per_trial - other.coverage_per_trial
        se = float(diff.std(ddof=1) / np.sqrt(diff.size)) if diff.size > 1 else float("nan")
        return float(diff.mean()), se


WITHIN_NOISE = ", within noise (|difference| < 2 s.e.)"
"""What a paired difference's reading says where :func:`within_noise` holds."""


def within_noise(mean: float, se: float) -> bool:
    """Whether a paired difference of ``mean`` ± ``se`` tells its two policies apart by no more than noise: |mean| < 2
    standard errors (an unknown s.e. tells nothing apart)."""
    return not abs(mean) >= 2.0 * se


def evaluate(
    cfg: ScenarioConfig,
    controller: Controller,
    trials: int | None = None,
    steps: int | None = None,
    seed: int = 0,
    on_step: StepHook | None = None,
) -> EvalResult:
    """Run ``trials`` independent arenas for ``steps`` steps; A = (1/T) Σ_t Σ_j g(B(t), j) per trial [paper].

    All trials run side by side as one batch. ``on_step`` (optional) sees every state and observation, e.g. to
    record a trial.
    """
    trials = cfg.test_trials if trials is None else trials
    steps = cfg.test_steps if steps is None else steps
    if trials < 1 or steps < 1:
        raise ValueError(f"trials and steps must be at least 1, got trials={trials}, steps={steps}")
    rng = np.random.default_rng(seed)
    world = reset(cfg, trials, rng)
    memory = controller.init(cfg, world, rng)
    obs = sense(cfg, world, rng)
    total = np.zeros(trials)
    spread = Cooperation.zeros(trials)
    for _ in range(steps):
        velocity, memory = controller.act(cfg, world, obs, memory, rng)
        world = step(cfg, world, velocity, rng)
        obs = sense(cfg, world, rng)
        total += coverage(cfg, obs)
        spread = spread.add(obs)
        if on_step is not None:
            on_step(world, obs)
    return EvalResult(coverage_per_trial=total / steps, cooperation=spread)
