"""The learner's typed figures: the live status it publishes and the report it writes at the end.

``LearnerStatus`` travels in a ``Status`` message's counters (names and meanings in docs/protocol.md); readers such
as ``ennc-ql up`` turn the counters back into it instead of reading them by name::

    status = LearnerStatus.from_counters(msg.counters)
    status.policy_version, status.coverage
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from algorithm.wire import figures_from_counters, status_counters


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
    """Messages refused (transport-level rejections plus experience of the wrong dimension)."""
    coverage: float = -1.0
    """Metric A (%) of the latest evaluation (-1: none yet)."""
    fits: int = 0
    """Phase-1 fits done."""
    elapsed: float = 0.0
    """Seconds of training."""

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
    rejected: int
    rejected_by_type: dict[str, int]
    increments: int
    stale_increments: int
    store_size: int
    overwritten: int
    policy_lag: dict[str, int]
    final_coverage_mean: float | None
    final_eval_trials: int
    eval_trials: int
    coverage_curve: list[list[float]]
    policy_file: str | None
    checkpoint: str
    seconds: float
    extra: dict[str, Any] = field(default_factory=dict)
    """Figures added by whoever ran the learner (``ennc-ql up``: run id, command, configuration, recording)."""

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        return {**out, **self.extra}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LearnerReport:
        names = {f.name for f in fields(cls)} - {"extra"}
        return cls(
            **{k: v for k, v in data.items() if k in names}, extra={k: v for k, v in data.items() if k not in names}
        )

    def with_extra(self, **extra: Any) -> LearnerReport:
        return dataclasses.replace(self, extra={**self.extra, **extra})
