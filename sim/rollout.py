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
class EvalResult:
    """Metric A of each trial, in percent of targets observed."""

    coverage_per_trial: np.ndarray

    @property
    def coverage_mean(self) -> float:
        return float(self.coverage_per_trial.mean())

    @property
    def coverage_std(self) -> float:
        return float(self.coverage_per_trial.std())


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
    for _ in range(steps):
        velocity, memory = controller.act(cfg, world, obs, memory, rng)
        world = step(cfg, world, velocity, rng)
        obs = sense(cfg, world, rng)
        total += coverage(cfg, obs)
        if on_step is not None:
            on_step(world, obs)
    return EvalResult(coverage_per_trial=total / steps)
