"""The learner's evaluator: the current policy on fixed seeded trials (metric A), the learning curve on development
trials and the final figure on the reported test trials.

Usage::

    evaluator = Evaluator(scenario("cmommt-v1"), trials=10, steps=1000, final_trials=50)
    evaluator.periodic(policy, at=61.0)      # a point of the learning curve (10 trials of DEVELOPMENT_SEED)
    evaluator.periodic(policy, 61.0, stop)   # the same, given up (EvaluationStopped) once the event is set
    evaluator.final(policy)                  # the final figure, on its own (50 trials of TEST_SEED)
    evaluator.final(policy, progress, stop)  # progress(done, total) after each part; EvaluationStopped once stop is set
    evaluator.curve                          # [(seconds, coverage %), ...]
    evaluator.latest                         # the newest point's coverage (None before the first evaluation)
    evaluator.references()                   # the hand-made controllers on the curve's trials
    evaluator.references(trials=50)          # ... and on the final figure's
    evaluator.comparison()                   # the final policy beside each of them: spread and paired difference
    meta = evaluator.to_meta(); evaluator.restore(meta)   # the curve survives a resume
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from algorithm.policy import OffLaw, Policy, PolicyController, evaluate_off_law
from algorithm.selection import DEVELOPMENT_SEED, TEST_SEED
from sim import CONTROLLERS, EvalResult, ScenarioConfig, evaluate


class EvaluationStopped(Exception):
    """An evaluation given up because the run stopped (a periodic one), or stopped again (the final one)."""


class Evaluator:
    def __init__(self, cfg: ScenarioConfig, trials: int, steps: int, final_trials: int) -> None:
        self.cfg = cfg
        self.trials = trials
        self.steps = steps
        self.final_trials = final_trials
        self.curve: list[tuple[float, float]] = []
        self.spread: dict[str, float] = {}
        """How the team of the newest evaluated policy spread over the targets (``sim.rollout.Cooperation``)."""
        self._references: dict[int, dict[str, EvalResult]] = {}
        self._final: EvalResult | None = None
        self._off_law: OffLaw | None = None
        self._team: tuple[EvalResult, OffLaw | None] | None = None

    def periodic(self, policy: Policy, at: float, stop: threading.Event | None = None) -> float:
        """Coverage (%) of ``policy``, kept on the curve at ``at`` seconds of training; EvaluationStopped (nothing
        kept) once ``stop`` is set, checked every step."""

        def check(*_: object) -> None:
            if stop is not None and stop.is_set():
                raise EvaluationStopped

        controller = PolicyController(policy)
        result = evaluate(self.cfg, controller, self.trials, self.steps, seed=DEVELOPMENT_SEED, on_step=check)
        self.curve.append((round(at, 2), round(result.coverage_mean, 3)))
        self.spread = _spread(result)
        return result.coverage_mean

    @property
    def latest(self) -> float | None:
        return self.curve[-1][1] if self.curve else None

    def references(self, trials: int | None = None) -> dict[str, float]:
        """Metric A (%) of the hand-made controllers on the curve's trials (``trials`` None) or on ``trials`` of the
        final figure's: the levels a figure is read against. Measured once each (0.4 s for the default 10 trials of
        1000 steps, on 2 busy cores)."""
        return {name: round(r.coverage_mean, 3) for name, r in self._reference_results(trials).items()}

    def reference_spread(self, trials: int | None = None) -> dict[str, dict[str, float]]:
        """How each hand-made controller's team spreads over the targets on the same trials as :meth:`references`."""
        return {name: _spread(r) for name, r in self._reference_results(trials).items()}

    def final(
        self,
        policy: Policy,
        progress: Callable[[int, int], None] | None = None,
        stop: threading.Event | None = None,
    ) -> float:
        """The final figure; the curve keeps one protocol, so this point stays off it. A policy of several robots'
        rows (option 2) is scored beside its rows merged into one team table (:meth:`team_table`), and every reference
        on the same trials (:meth:`comparison`). ``progress(done, total)`` follows each of these parts;
        EvaluationStopped (nothing kept) once ``stop`` is set, checked every step."""

        def check(*_: object) -> None:
            if stop is not None and stop.is_set():
                raise EvaluationStopped

        scored = self.final_trials in self._references
        total = 1 + (policy.tables.shape[0] > 1) + (0 if scored else len(CONTROLLERS))
        done = 0

        def step() -> None:
            nonlocal done
            done += 1
            if progress is not None:
                progress(done, total)

        final = evaluate_off_law(self.cfg, policy, self.final_trials, self.steps, TEST_SEED, on_step=check)
        step()
        team = None
        if policy.tables.shape[0] > 1:
            team = evaluate_off_law(self.cfg, policy.team(), self.final_trials, self.steps, TEST_SEED, on_step=check)
            step()
        if not scored:
            references = {}
            for name, controller in CONTROLLERS.items():
                result = evaluate(self.cfg, controller, self.final_trials, self.steps, seed=TEST_SEED, on_step=check)
                references[name] = result
                step()
            self._references[self.final_trials] = references
        (self._final, self._off_law), self._team = final, team
        return self._final.coverage_mean

    def team_table(self) -> dict[str, float] | None:
        """The final policy's rows merged into one table, on the final figure's trials: its coverage, its decisions
        off the law, and the paired difference of the per-robot policy from it (``per_robot_minus`` ± s.e.); None
        when the final policy has one row."""
        if self._final is None or self._team is None:
            return None
        team, off = self._team
        mean, se = self._final.minus(team)
        row = {"coverage": round(team.coverage_mean, 3), "per_robot_minus": round(mean, 3)}
        row["per_robot_minus_se"] = round(se, 3)
        if off is not None:
            row["off_law_pct"] = round(off.pct, 3)
        return row

    def comparison(self) -> dict[str, dict[str, float]]:
        """The final policy (``learned``) and every reference on the final figure's trials: coverage, the team's
        spread over the targets (and for a law action set's policy ``off_law_pct``, its decisions off the move law),
        and for each reference the paired difference learned − it with its standard
        error; empty before :meth:`final`."""
        if self._final is None:
            return {}
        rows = {"learned": {"coverage": round(self._final.coverage_mean, 3), **_spread(self._final)}}
        if self._off_law is not None:
            rows["learned"]["off_law_pct"] = round(self._off_law.pct, 3)
            rows["learned"]["shared_decisions_pct"] = round(self._off_law.shared_pct, 3)
            rows["learned"]["shared_off_law_pct"] = round(self._off_law.shared_off_pct, 3)
        for name, result in self._reference_results(self.final_trials).items():
            mean, se = self._final.minus(result)
            rows[name] = {
                "coverage": round(result.coverage_mean, 3),
                **_spread(result),
                "learned_minus": round(mean, 3),
                "learned_minus_se": round(se, 3),
            }
        return rows

    def _reference_results(self, trials: int | None) -> dict[str, EvalResult]:
        """The references on the curve's trials (``trials`` None) or on the final figure's (that many of the test
        seed's)."""
        key = -1 if trials is None else trials
        if key not in self._references:
            count, seed = (self.trials, DEVELOPMENT_SEED) if trials is None else (trials, TEST_SEED)
            self._references[key] = {
                name: evaluate(self.cfg, controller, count, self.steps, seed=seed)
                for name, controller in CONTROLLERS.items()
            }
        return self._references[key]

    def to_meta(self) -> dict[str, Any]:
        return {"coverage_curve": list(self.curve)}

    def restore(self, meta: dict[str, Any]) -> None:
        self.curve = [(float(t), float(c)) for t, c in meta["coverage_curve"]]


def _spread(result: EvalResult) -> dict[str, float]:
    spread = {} if result.cooperation is None else result.cooperation.summary()
    return {k: round(v, 3) for k, v in spread.items()}
