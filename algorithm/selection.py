"""Keep the best policy of a learning run by its score on validation trials, never on the reported test trials.

Phase 2 does not improve monotonically: a run can settle early on a worse policy and stay there (the scaling runs
of docs/learning-quality.md spread 66.6–74.9 % at 16 minutes). The learner and ``train`` therefore score each
policy they would evaluate on validation trials too, and save and report the best one. Every policy is scored on
the same validation trials, so two scores differ by the policies, not by the trials::

    keeper = BestPolicy(scenario("cmommt-v1"), trials=10, steps=1000)
    keeper.offer(policy, at=61.0)        # its validation coverage (%); kept if above every earlier one
    keeper.keep(policy, keeper.score(policy), at=61.0)   # the same in two halves: the slow score records nothing
    keeper.best                          # Kept(policy, coverage, at) or None before the first offer
    keeper.to_meta(); keeper.restore(meta, policy)   # across a learner's resume (the policy from its file)

A law action set's policy is then read with the margin that scores best on validation trials (more of them: the
margins differ by tenths of a point), never on the reported ones::

    choice = choose_margin(cfg, policy, trials=300, steps=1000)   # MarginChoice(margin, scores, spreads, ...)
    policy = dataclasses.replace(policy, law_margin=choice.margin)

A choice can be held to a hand-made law's spread over the targets: a margin (or a candidate) whose team has more
robots per covered target on the validation trials than the law's team there is chosen only where none has fewer::

    cap = reference_spread(cfg, "a-cmommt", trials=300, steps=1000)   # the law's robots per covered target
    choice = choose_margin(cfg, policy, trials=300, steps=1000, cap=cap)
    rank(coverage, spread, cap)          # the order of two candidates: (within the cap, coverage)
"""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass, field
from typing import Any

from algorithm.policy import Policy, PolicyController
from sim import ScenarioConfig, evaluate
from sim.controllers import HAND_MADE

VALIDATION_SEED = 1000
"""The validation trials' seed: none of the reported test trials (seed 0 for ``up`` and ``train``, 0…3 for the
README's tables), nor the references' tuning seeds and the screens' test trials (100…103)."""


LAW_MARGINS = (0.0, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0)
"""The margins :func:`choose_margin` tries: 0 is the plain argmax; at 2 the tables of every policy measured departed
from ``law`` in under 1 % of the decisions, so the policy is nearly the law itself (docs/learning-quality.md,
"Eighteenth round") [choice]."""


class ScoringStopped(Exception):
    """A margin choice given up because its ``stop`` was set."""


@dataclass(frozen=True, slots=True)
class MarginChoice:
    margin: float
    """The margin that scored best (the smallest on a tie)."""
    scores: dict[float, float]
    """Metric A (%) on the validation trials of the policy read with each margin tried."""
    trials: int
    seed: int
    spreads: dict[float, float] = field(default_factory=dict)
    """Robots per covered target on the same trials with each margin tried (empty: not recorded, as in a checkpoint
    written before they were)."""


def within(spread: float | None, cap: float | None) -> bool:
    """Whether a team of ``spread`` robots per covered target is held to ``cap`` (None: no cap; an unknown or NaN
    spread is not within one)."""
    return cap is None or (spread is not None and spread <= cap)


def rank(coverage: float, spread: float | None, cap: float | None) -> tuple[bool, float]:
    """The order of candidates under a spread cap: every one within the cap before any other, then by coverage."""
    return within(spread, cap), coverage


def reference_spread(cfg: ScenarioConfig, name: str, trials: int, steps: int, seed: int = VALIDATION_SEED) -> float:
    """Robots per covered target of the hand-made controller ``name`` on the validation trials: the cap of a choice
    held to its spread."""
    result = evaluate(cfg, HAND_MADE[name], trials, steps, seed=seed)
    spread = result.robots_per_covered_target
    if not spread > 0:
        raise ValueError(f"{name} covered no target on {trials} validation trials: its spread caps nothing")
    return spread


def choose_margin(
    cfg: ScenarioConfig,
    policy: Policy,
    trials: int,
    steps: int,
    margins: tuple[float, ...] = LAW_MARGINS,
    seed: int = VALIDATION_SEED,
    stop: threading.Event | None = None,
    cap: float | None = None,
) -> MarginChoice:
    """The ``law_margin`` among ``margins`` with which ``policy`` (a law action set's) scores best on the validation
    trials, every margin on the same trials; with a ``cap``, the best of those whose robots per covered target are at
    most it, where one is (:func:`rank`). The smallest margin on a tie. ScoringStopped once ``stop`` is set, checked
    before each margin."""
    if policy.formulation.actions.law is None:
        raise ValueError(f"a law margin needs a law action set, not {policy.formulation.actions.name!r}")
    scores, spreads = {}, {}
    for m in margins:
        if stop is not None and stop.is_set():
            raise ScoringStopped
        controller = PolicyController(dataclasses.replace(policy, law_margin=m))
        result = evaluate(cfg, controller, trials, steps, seed=seed)
        scores[m] = result.coverage_mean
        spreads[m] = result.robots_per_covered_target
    best = max(margins, key=lambda m: (*rank(scores[m], spreads[m], cap), -m))
    return MarginChoice(best, scores, trials, seed, spreads)


@dataclass(frozen=True, slots=True)
class Kept:
    policy: Policy
    coverage: float
    """Metric A (%) on the validation trials."""
    at: float
    """When it was offered: seconds of training (the learner) or phase-2 batches (``train``)."""


class BestPolicy:
    def __init__(self, cfg: ScenarioConfig, trials: int, steps: int, seed: int = VALIDATION_SEED) -> None:
        self.cfg = cfg
        self.trials = trials
        self.steps = steps
        self.seed = seed
        self.best: Kept | None = None
        self.scores: list[tuple[float, float]] = []
        """(at, validation coverage %) of every policy offered."""

    def offer(self, policy: Policy, at: float) -> float:
        """Score ``policy`` on the validation trials and keep it if it beats every earlier one (ties keep the
        earlier); returns its score."""
        coverage = self.score(policy)
        self.keep(policy, coverage, at)
        return coverage

    def score(self, policy: Policy) -> float:
        """Metric A (%) of ``policy`` on the validation trials; records nothing (the slow half of :meth:`offer`)."""
        return evaluate(self.cfg, PolicyController(policy), self.trials, self.steps, seed=self.seed).coverage_mean

    def keep(self, policy: Policy, coverage: float, at: float) -> bool:
        """Record ``policy``'s validation ``coverage``; True if it is the new best (the quick half of :meth:`offer`)."""
        self.scores.append((round(at, 2), round(coverage, 3)))
        if self.best is None or coverage > self.best.coverage:
            self.best = Kept(policy, coverage, at)
            return True
        return False

    def to_meta(self) -> dict[str, Any]:
        kept = None if self.best is None else {"coverage": self.best.coverage, "at": self.best.at}
        return {"validation_scores": list(self.scores), "kept": kept}

    def restore(self, meta: dict[str, Any], policy: Policy | None) -> None:
        """Continue from a checkpoint's figures and the kept policy (None: none was kept, or its file is lost, so
        the next offer is kept)."""
        self.scores = [(float(t), float(c)) for t, c in meta.get("validation_scores", [])]
        kept = meta.get("kept")
        self.best = None if kept is None or policy is None else Kept(policy, float(kept["coverage"]), float(kept["at"]))
