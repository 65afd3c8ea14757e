"""What the learner shows in the viewer, as the actor's :class:`monitor.trial.TrialWatch` does for a trial.

Usage (the learner's loop; every method returns at once when the monitor is off, before any work is done)::

    watch = LearnerWatch(monitor, cfg, clock=run_clock)       # train_time: the learner's run clock
    watch.started(formulation, evaluator.references)          # once: the curve's name and reference levels
    watch.status(status, actors=["actor-0"], lag={"actor-0": 1})    # each status publish: one learner_step
    watch.policy(policy)                                      # a new discretization: prototypes and Q statistics
    watch.evaluated(policy, 61.2)                             # a point of the learning curve
    watch.final(policy, 63.0, trials=50)                      # the final figure
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

from monitor.interface import Monitor

if TYPE_CHECKING:
    from algorithm.policy import Policy
    from sim.config import ScenarioConfig
    from sim.formulation import Formulation

log = logging.getLogger(__name__)


class StatusFigures(Protocol):
    """The learner's status figures the viewer plots (``learner.report.LearnerStatus`` has them)."""

    @property
    def policy_version(self) -> int: ...
    @property
    def tuples_per_s(self) -> float: ...
    @property
    def live_actors(self) -> int: ...
    @property
    def store_size(self) -> int: ...
    @property
    def rejected(self) -> int: ...


class LearnerWatch:
    def __init__(self, monitor: Monitor, cfg: ScenarioConfig, clock: Callable[[], float]) -> None:
        self.monitor = monitor
        self.cfg = cfg
        self.step = 0
        """Status publishes so far: the ``learner_step`` timeline; evaluations carry the step they ran in."""
        self._laid_out: list[str] | None = None  # actors in the viewer layout last sent
        monitor.use_clock(clock)

    def started(self, formulation: Formulation, references: Callable[[], Mapping[str, float]]) -> None:
        """Name the learning curve by its formulation, lay the prototype views out by its moves, and draw the
        reference levels ``references()`` measures."""
        if not self.monitor.enabled:
            return
        self.monitor.formulation(formulation)
        began = time.monotonic()
        levels = references()
        self.monitor.reference_levels(levels)
        log.info("reference levels on the test trials (%.1f s): %s", time.monotonic() - began, dict(levels))

    def status(self, status: StatusFigures, actors: Sequence[str], lag: Mapping[str, int]) -> None:
        """One status publish: the figures, each actor's policy lag, and a new layout when an actor joined."""
        if not self.monitor.enabled:
            return
        self.step += 1
        if list(actors) != self._laid_out:  # a new actor gets its arena view
            self._laid_out = list(actors)
            self.monitor.send_blueprint(
                self._laid_out, arena_radius=self.cfg.arena_radius, sensing_range=self.cfg.sensing_range
            )
        self.monitor.learner_metrics(
            learner_step=self.step,
            policy_version=status.policy_version,
            tuples_per_s=status.tuples_per_s,
            live_actors=status.live_actors,
            store_size=status.store_size,
            rejected=status.rejected,
            lag=lag,
        )

    def policy(self, policy: Policy) -> None:
        """Prototypes coloured by their Q value (mean over robots) and the tables' statistics."""
        if not self.monitor.enabled:
            return
        prototypes, q_values = policy.prototypes_by_action()
        scale = policy.discretization.scale
        if scale is not None:  # drawn in arena units, so the views' range is the sensing range
            prototypes = [p * scale for p in prototypes]
        self.monitor.prototypes(prototypes, q_values, policy_version=policy.version)
        self.monitor.q_stats([policy.tables], policy_version=policy.version, learner_step=self.step)

    def evaluated(
        self, policy: Policy, coverage: float, spread: Mapping[str, Mapping[str, float]], trials: int
    ) -> None:
        """A point of the learning curve, with the policy it measured and how its team and the references' spread
        over the targets on those ``trials``."""
        if not self.monitor.enabled:
            return
        self.monitor.eval_coverage(coverage, policy_version=policy.version, learner_step=self.step)
        self.monitor.cooperation(spread, trials=trials, policy_version=policy.version, learner_step=self.step)
        self.policy(policy)

    def final(
        self, policy: Policy, coverage: float, trials: int, comparison: Mapping[str, Mapping[str, float]]
    ) -> None:
        """The final figure on ``trials`` test trials, with the policy it measured and its comparison with the
        references on those trials (:meth:`learner.evaluator.Evaluator.comparison`)."""
        if not self.monitor.enabled:
            return
        self.monitor.final_coverage(coverage, trials=trials, policy_version=policy.version, learner_step=self.step)
        self.monitor.cooperation(comparison, trials=trials, policy_version=policy.version, learner_step=self.step)
        self.policy(policy)
