"""The learner's typed figures: the live status it publishes and the report it writes at the end.

``LearnerStatus`` travels in a ``Status`` message's counters (names and meanings in docs/reference/protocol.md); readers
such as ``ennc-ql up`` turn the counters back into it instead of reading them by name. Both are built from the learner's
parts, never field by field by the learner::

    status = LearnerStatus.of(intake.figures(), state, members, evaluator, fits=fitter.fits, elapsed=clock())
    report = LearnerReport.of(config, status, figures, state, members, evaluator, final, policy_file, checkpoint,
                              resumes)
    status = LearnerStatus.from_counters(msg.counters)
    status.policy_version, status.coverage
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from algorithm.wire import figures_from_counters, status_counters

if TYPE_CHECKING:  # the parts; readers of the figures (``ennc-ql up``) need none of them
    from algorithm.selection import SavedPolicy
    from learner.config import LearnerConfig
    from learner.evaluator import Evaluator
    from learner.intake import IntakeFigures
    from learner.membership import Membership
    from learner.policy_state import PolicyState


@dataclass(frozen=True, slots=True)
class LearnerStatus:
    tuples_received: int = 0
    """Tuples stored over the whole run (duplicates excluded)."""
    store_size: int = 0
    """Tuples in the store now."""
    overwritten: int = 0
    """Tuples dropped because the store was full (the oldest go first)."""
    duplicates: int = 0
    """Batches and increments received again and ignored (re-sends)."""
    gaps: int = 0
    """Sequence numbers skipped so far (below the highest seen, never received)."""
    policy_version: int = 0
    """Version of the latest broadcast policy (0: none yet)."""
    live_actors: int = 0
    """Actors whose liveliness token is present."""
    tuples_per_s: float = 0.0
    """Tuples stored per second since this process started."""
    policy_lag_max: int = 0
    """Largest number of versions an actor's newest experience is behind the current policy."""
    rejected: int = 0
    """Messages refused over the run, each once (invalid, or experience of another state dimension)."""
    coverage: float | None = None
    """Metric A (%) of the latest evaluation (None, and no counter sent: none yet)."""
    fits: int = 0
    """Phase-1 fits done."""
    elapsed: float = 0.0
    """Seconds of training."""
    scoring: float | None = None
    """Share (0-1) of the final evaluation done, in the wind-down (None, and no counter sent: not under way)."""

    @classmethod
    def of(
        cls,
        intake: IntakeFigures,
        state: PolicyState,
        members: Membership,
        evaluator: Evaluator,
        fits: int,
        elapsed: float,
        scoring: float | None = None,
    ) -> LearnerStatus:
        return cls(
            tuples_received=intake.tuples_received,
            store_size=intake.store_size,
            overwritten=intake.overwritten,
            duplicates=intake.duplicates,
            gaps=intake.gaps,
            policy_version=state.version,
            live_actors=len(members.live()),
            tuples_per_s=intake.tuples_per_s,
            policy_lag_max=max(state.lag(intake.latest_version).values(), default=0),
            rejected=intake.rejected,
            coverage=evaluator.latest,
            fits=fits,
            elapsed=elapsed,
            scoring=scoring,
        )

    def to_counters(self) -> dict[str, float]:
        return status_counters(self)

    @classmethod
    def from_counters(cls, counters: Mapping[str, float]) -> LearnerStatus:
        """Unknown names are ignored and missing ones keep their defaults (a newer or older learner)."""
        return figures_from_counters(cls, counters)


@dataclass(frozen=True, slots=True)
class LearnerReport:
    """What ``report.json`` holds at the end of a learner's run."""

    learner_id: str
    actors: list[str]
    """Every actor seen in the run."""
    live_actors: list[str]
    tuples_received: int
    tuples_by_actor: dict[str, int]
    tuples_per_s: float
    """Tuples stored per second of training, over the whole run (resumes included)."""
    policy_version: int
    phase1_fits: int
    prototypes_per_action: list[int]
    duplicates: int
    gaps: int
    out_of_order: int
    """Messages that arrived before an earlier one of their sender, which came later (or, counted in ``gaps``,
    never): usual, since experience and table increments travel on two subscriptions."""
    rejected: int
    rejected_by_type: dict[str, int]
    """Messages refused, each once, by error class (docs/reference/protocol.md §6) or ``StateDimension``."""
    refused_tokens: int
    """Liveliness tokens refused because their id is not an identifier (not listed among ``actors``)."""
    increments: int
    stale_increments: int
    store_size: int
    overwritten: int
    policy_lag: dict[str, int]
    final_coverage_mean: float | None
    final_eval_trials: int
    eval_trials: int
    coverage_curve: list[list[float]]
    reference_coverage: dict[str, float]
    """Metric A (%) of each hand-made controller and the oracle (``sim.CONTROLLERS``) on the curve's test trials;
    empty when no policy was learned."""
    final_reference_coverage: dict[str, float]
    """The same on the final figure's test trials: the levels the final coverage is read against."""
    final_comparison: dict[str, dict[str, float]]
    """On the final figure's trials, the final policy (``learned``) and every reference: ``coverage``, how the team
    spread over the targets per robot-step (``only_shared_pct``, ``none_in_view_pct``,
    ``robots_per_covered_target``), for a law action set's learned policy the percentage of its robots' decisions
    that took another move than law (``off_law_pct``), of those taken where a teammate shared the robot's targets
    (``shared_decisions_pct``) and how many of these did (``shared_off_law_pct``); for a reference, the paired
    difference learned − it (``learned_minus``) with its standard error (``learned_minus_se``). Empty when no
    policy was learned."""
    policy_file: str | None
    checkpoint: str
    seconds: float
    team_table: dict[str, float] | None = None
    """With per-robot tables saved (option 2): their rows merged into one team table, scored on the same final trials
    (``coverage``, ``off_law_pct``) and the paired difference per-robot − team (``per_robot_minus`` ± s.e.); None for
    a one-table policy or before a final figure."""
    base_law: str = "a-cmommt"
    """The hand-made controller the learned policy is measured against first (``sim.formulation.Formulation.base_law``:
    for a law action set the law its move ``law`` follows): what learning added is the paired difference from it."""
    saved: dict[str, Any] | None = None
    """Which policy the run saved and why (``algorithm.selection.SavedPolicy.to_dict``): its ``version``, the run
    clock it was made at (``at_s``), a law action set's ``margin``, how the margin was chosen (``choice``: every
    margin's ``validation_coverage`` and ``validation_spread`` on ``validation_trials`` of ``validation_seed``;
    None where it was given) and the rule's ``reason``; None before a policy was learned."""
    resumes: list[dict[str, Any]] = field(default_factory=list)
    """Every time the run was resumed from its checkpoint: the run clock it resumed at (``at_s``), the policy version
    of its first broadcast, that broadcast's wall time and the seconds from the process's start to it."""

    @classmethod
    def of(
        cls,
        config: LearnerConfig,
        status: LearnerStatus,
        intake: IntakeFigures,
        state: PolicyState,
        members: Membership,
        evaluator: Evaluator,
        final: float | None,
        policy_file: Path | None,
        checkpoint: Path,
        resumes: list[dict[str, Any]] | None = None,
        saved: SavedPolicy | None = None,
    ) -> LearnerReport:
        """The report of a run that ended with ``status`` (built from the same ``intake`` figures) and the final
        figure ``final`` (None: no policy was learned, and no reference is measured)."""
        disc = state.discretization
        return cls(
            learner_id=config.learner_id,
            actors=members.seen(),
            live_actors=members.live(),
            tuples_received=status.tuples_received,
            tuples_by_actor=intake.tuples_by_actor,
            tuples_per_s=round(status.tuples_received / max(status.elapsed, 1e-9), 1),
            policy_version=status.policy_version,
            phase1_fits=status.fits,
            prototypes_per_action=[] if disc is None else [int(s) for s in disc.sizes()],
            duplicates=status.duplicates,
            gaps=status.gaps,
            out_of_order=intake.out_of_order,
            rejected=status.rejected,
            rejected_by_type=intake.rejected_by_type,
            refused_tokens=members.refused,
            increments=state.increments,
            stale_increments=state.stale_increments,
            store_size=status.store_size,
            overwritten=status.overwritten,
            policy_lag=state.lag(intake.latest_version),
            final_coverage_mean=None if final is None else round(final, 3),
            final_eval_trials=config.final_eval_trials,
            eval_trials=config.eval_trials,
            coverage_curve=[list(p) for p in evaluator.curve],
            reference_coverage={} if final is None else evaluator.references(),
            final_reference_coverage={} if final is None else evaluator.references(config.final_eval_trials),
            final_comparison={} if final is None else evaluator.comparison(),
            policy_file=None if policy_file is None else str(policy_file),
            checkpoint=str(checkpoint),
            seconds=round(status.elapsed, 2),
            resumes=list(resumes or []),
            team_table=None if final is None else evaluator.team_table(),
            base_law=config.resolved.base_law,
            saved=None if saved is None else saved.to_dict(),
        )

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LearnerReport:
        """The learner's figures of ``data`` (``report.json``); the launcher's keys beside them are
        ``tools.cluster.report.RunReport``'s to read."""
        names = {f.name for f in fields(cls)}
        # Reports written before these figures existed lack them.
        known = {
            "reference_coverage": {},
            "final_reference_coverage": {},
            "final_comparison": {},
            "out_of_order": 0,
            "refused_tokens": 0,
            **{k: v for k, v in data.items() if k in names},
        }
        return cls(**known)

    @property
    def saved_policy(self) -> SavedPolicy | None:
        """``saved`` as the typed record it was written from."""
        from algorithm.selection import SavedPolicy  # readers of the status alone (up's progress) need none of it

        return None if self.saved is None else SavedPolicy.from_dict(self.saved)
