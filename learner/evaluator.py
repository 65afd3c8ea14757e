"""The learner's evaluator: the current policy on fixed seeded test trials (metric A), and the learning curve.

Usage::

    evaluator = Evaluator(scenario("cmommt-v1"), trials=10, steps=1000, final_trials=50)
    evaluator.periodic(policy, at=61.0)      # a point of the learning curve (10 trials)
    evaluator.final(policy)                  # the final figure, on its own (50 trials)
    evaluator.curve                          # [(seconds, coverage %), ...]
    evaluator.latest                         # the newest point's coverage (None before the first evaluation)
    evaluator.references()                   # the hand-made controllers on the curve's trials
    evaluator.references(trials=50)          # ... and on the final figure's
    meta = evaluator.to_meta(); evaluator.restore(meta)   # the curve survives a resume
"""

from __future__ import annotations

from typing import Any

from algorithm.policy import Policy, PolicyController
from sim import HAND_MADE, ScenarioConfig, evaluate

TEST_SEED = 0
"""Every evaluation runs the same trials, as the hand-made controllers' figures do."""


class Evaluator:
    def __init__(self, cfg: ScenarioConfig, trials: int, steps: int, final_trials: int) -> None:
        self.cfg = cfg
        self.trials = trials
        self.steps = steps
        self.final_trials = final_trials
        self.curve: list[tuple[float, float]] = []
        self._references: dict[int, dict[str, float]] = {}

    def periodic(self, policy: Policy, at: float) -> float:
        """Coverage (%) of ``policy``, kept on the curve at ``at`` seconds of training."""
        coverage = self._coverage(policy, self.trials)
        self.curve.append((round(at, 2), round(coverage, 3)))
        return coverage

    @property
    def latest(self) -> float | None:
        return self.curve[-1][1] if self.curve else None

    def references(self, trials: int | None = None) -> dict[str, float]:
        """Metric A (%) of the hand-made controllers on these same test trials (``trials``: the first that many;
        default the curve's): the levels a figure is read against. Measured once per trial count (0.4 s for the
        default 10 trials of 1000 steps, on 2 busy cores)."""
        trials = self.trials if trials is None else trials
        if trials not in self._references:
            self._references[trials] = {
                name: round(evaluate(self.cfg, controller, trials, self.steps, seed=TEST_SEED).coverage_mean, 3)
                for name, controller in HAND_MADE.items()
            }
        return self._references[trials]

    def final(self, policy: Policy) -> float:
        """The final figure; the curve keeps one protocol, so this point stays off it."""
        return self._coverage(policy, self.final_trials)

    def to_meta(self) -> dict[str, Any]:
        return {"coverage_curve": list(self.curve)}

    def restore(self, meta: dict[str, Any]) -> None:
        self.curve = [(float(t), float(c)) for t, c in meta["coverage_curve"]]

    def _coverage(self, policy: Policy, trials: int) -> float:
        return evaluate(self.cfg, PolicyController(policy), trials, self.steps, seed=TEST_SEED).coverage_mean
