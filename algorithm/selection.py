"""Which policy a training run saves: one rule, one owner, one typed record.

Every training path (the learner behind ``ennc-ql up``, ``train`` behind ``ablate`` and ``reproduce``) saves the
tables its whole experience made, the last ones, never an earlier version chosen on a score: a choice among versions
moves a figure without better learning, and throws away the experience that came after. The one choice left is how a
law action set's tables are read: the law margin (a robot departs from the move law only where another move's value
beats it by more), given, or chosen on validation trials of their own seed, never on the reported test trials::

    rule = SaveRule(scenario("cmommt-v1"), law_margin=None, trials=300, steps=1000)
    policy, saved = rule.decide(last_policy, at=480.0)     # the policy read as it is saved, and the record of why
    saved.margin, saved.choice.scores                     # the margin and every margin's validation coverage
    saved.to_dict(); SavedPolicy.from_dict(d)             # report.json's ``saved`` and back

A choice can be given up: ``rule.decide(policy, at, stop=event)`` raises :class:`ScoringStopped` once ``event`` is
set, between two margins; a run stopped so saves ``rule.fallback(policy, at)``, the same tables unchosen.
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from algorithm.policy import Policy, PolicyController
from sim import ScenarioConfig, evaluate

VALIDATION_SEED = 1000
"""The validation trials' seed: none of the reported test trials (:data:`TEST_SEED`), nor the references' tuning
seeds (100…103) [choice]."""
TEST_SEED = 5000
"""The reported test trials' seed: the final figures of ``up``, ``eval`` and the README read these trials and no
design choice has (seeds 0, 2000 and 3000 steered earlier choices and are development trials now) [choice]."""
DEVELOPMENT_SEED = 0
"""The learning curve's trials: read many times during a run, so development trials, never the reported ones."""

LAW_MARGINS = (0.0, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0)
"""The margins :class:`SaveRule` tries: 0 is the plain argmax; at 2 the tables of every policy measured departed from
``law`` in under 1 % of the decisions, so the policy is nearly the law itself [choice]."""


FALLBACK_MARGIN = 1.0
"""The margin of a run stopped before its choice: the one that most often scored best on validation trials over the
learner's recent runs, and where tables departed from ``law`` on about a third of the decisions [choice]."""


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
    """Robots per covered target on the same trials with each margin tried: reported, never a gate."""


def choose_margin(
    cfg: ScenarioConfig,
    policy: Policy,
    trials: int,
    steps: int,
    margins: tuple[float, ...] = LAW_MARGINS,
    seed: int = VALIDATION_SEED,
    stop: threading.Event | None = None,
) -> MarginChoice:
    """The ``law_margin`` among ``margins`` with which ``policy`` (a law action set's) scores best on the validation
    trials, every margin on the same trials; the smallest on a tie. ScoringStopped once ``stop`` is set, checked
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
    best = max(margins, key=lambda m: (scores[m], -m))
    return MarginChoice(best, scores, trials, seed, spreads)


@dataclass(frozen=True, slots=True)
class SavedPolicy:
    """The record of what a run saved: reports print it, nothing decides again from it."""

    version: int
    """The policy version saved (the last the run made)."""
    at_s: float
    """The run clock (seconds of training) when it was made."""
    margin: float | None
    """A law action set's margin it is read with (None: another action set, read by the argmax)."""
    choice: MarginChoice | None = None
    """How the margin was chosen on validation trials (None: given, or not a law action set)."""
    reason: str = ""
    """Why it is read so, in a few words (the rule's own)."""

    def to_dict(self) -> dict[str, Any]:
        c = self.choice
        return {
            "version": self.version,
            "at_s": round(self.at_s, 2),
            "margin": self.margin,
            "reason": self.reason,
            "choice": None
            if c is None
            else {
                "validation_coverage": {f"{m:g}": round(v, 3) for m, v in c.scores.items()},
                "validation_spread": {f"{m:g}": round(v, 4) for m, v in c.spreads.items()},
                "validation_trials": c.trials,
                "validation_seed": c.seed,
            },
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> SavedPolicy:
        c = data.get("choice")
        choice = (
            None
            if c is None
            else MarginChoice(
                float(data["margin"]),
                {float(m): float(v) for m, v in c["validation_coverage"].items()},
                int(c["validation_trials"]),
                int(c["validation_seed"]),
                {float(m): float(v) for m, v in c.get("validation_spread", {}).items()},
            )
        )
        margin = data.get("margin")
        return cls(
            int(data["version"]),
            float(data["at_s"]),
            None if margin is None else float(margin),
            choice,
            str(data.get("reason", "")),
        )


@dataclass(frozen=True, slots=True)
class SaveRule:
    """The rule every training path saves by: the last policy, a law action set's read with ``law_margin`` (given)
    or with the margin of :data:`LAW_MARGINS` that scores best on ``trials`` validation trials (``law_margin`` None)."""

    cfg: ScenarioConfig
    law_margin: float | None
    trials: int
    steps: int

    def decide(self, policy: Policy, at: float, stop: threading.Event | None = None) -> tuple[Policy, SavedPolicy]:
        """``policy`` (the last) read as it is saved, and the record of it. ScoringStopped once ``stop`` is set
        during a margin choice."""
        if policy.formulation.actions.law is None:
            return policy, SavedPolicy(policy.version, at, None, None, "the last tables, by their argmax")
        if self.law_margin is not None:
            read = dataclasses.replace(policy, law_margin=self.law_margin)
            return read, SavedPolicy(policy.version, at, self.law_margin, None, "the last tables, the margin given")
        choice = choose_margin(self.cfg, policy, self.trials, self.steps, stop=stop)
        read = dataclasses.replace(policy, law_margin=choice.margin)
        reason = f"the last tables, the margin that scored best on {self.trials} validation trials"
        return read, SavedPolicy(policy.version, at, choice.margin, choice, reason)

    def fallback(self, policy: Policy, at: float) -> tuple[Policy, SavedPolicy]:
        """``policy`` read without a choice, for a run stopped before its choice ended: with ``law_margin`` where
        given, else with :data:`FALLBACK_MARGIN`."""
        if policy.formulation.actions.law is None or self.law_margin is not None:
            return self.decide(policy, at)
        read = dataclasses.replace(policy, law_margin=FALLBACK_MARGIN)
        reason = f"the last tables, margin {FALLBACK_MARGIN:g}: the run stopped before a margin was chosen"
        return read, SavedPolicy(policy.version, at, FALLBACK_MARGIN, None, reason)
