"""Names shared by every process that logs into the one recording: application id, timelines, entity paths.

Paths are written without a leading ``/``; Rerun treats ``a/b`` and ``/a/b`` alike.
"""

from __future__ import annotations

from pathlib import Path

APPLICATION_ID = "ennc-ql"
"""Every process logs under this application id; together with a shared recording id it makes one recording."""

# -- timelines --------------------------------------------------------------------------------------------------

SIM_STEP = "sim_step"
"""Sequence: an actor's simulation step counter (steps of its batch of arenas since it started), or the step of a
recorded test trial."""
POLICY_VERSION = "policy_version"
"""Sequence: the learner's policy version."""
LEARNER_STEP = "learner_step"
"""Sequence: iterations of the learner's main loop (one per status publish); evaluation points carry the
iteration they ran in."""
WALL_TIME = "wall_time"
"""Timestamp: seconds since the Unix epoch at the logging process; the one timeline every row carries, so series
from different processes line up on it."""

# -- learner ----------------------------------------------------------------------------------------------------

LEARNER = "learner"
LEARNER_COVERAGE_EVAL = "learner/coverage/eval"
"""Metric A (%) of the current policy on the seeded test trials."""
LEARNER_TUPLES_PER_S = "learner/tuples_per_s"
LEARNER_POLICY_VERSION = "learner/policy_version"
LEARNER_LIVE_ACTORS = "learner/live_actors"
LEARNER_STORE_SIZE = "learner/store_size"
LEARNER_REJECTED = "learner/rejected"
LEARNER_LAG = "learner/lag"
"""Parent of ``learner/lag/<actor_id>``: policy versions an actor's latest experience lags behind."""
LEARNER_Q = "learner/q"
"""Parent of ``learner/q/mean``, ``learner/q/min``, ``learner/q/max`` over every Q table entry."""
LEARNER_PROTOTYPES = "learner/prototypes"
"""Parent of ``learner/prototypes/action_<k>``."""

Q_STATS = ("mean", "min", "max")

# -- actors -----------------------------------------------------------------------------------------------------

ACTORS = "actors"
ACTOR_COVERAGE = "coverage"
ACTOR_REWARD = "reward"
ACTOR_TUPLES_PER_S = "tuples_per_s"
ACTOR_POLICY_VERSION = "policy_version"

# -- a recorded test trial (``ennc-ql eval``) --------------------------------------------------------------------

EVAL = "eval"
EVAL_ARENA = "eval/arena"
EVAL_COVERAGE_NAME = "coverage"
EVAL_COVERAGE = f"{EVAL}/{EVAL_COVERAGE_NAME}"
"""Per-step coverage (%) of the recorded trial."""

# -- the parts of an arena view, under its origin -----------------------------------------------------------------

ARENA_BOUNDARY = "boundary"
ARENA_SENSING = "sensing"
ARENA_ROBOTS = "robots"
ARENA_TARGETS = "targets"

RECORDING_FILE = "recording.rrd"
"""Name of the merged recording in a run folder."""


def actor(actor_id: str, metric: str) -> str:
    """``actors/<actor_id>/<metric>``, e.g. ``actor("actor-0", ACTOR_COVERAGE)``."""
    return f"{ACTORS}/{actor_id}/{metric}"


def actor_arena(actor_id: str) -> str:
    """Origin of an actor's arena view: ``actors/<actor_id>/arena``."""
    return f"{ACTORS}/{actor_id}/arena"


def learner_lag(actor_id: str) -> str:
    return f"{LEARNER_LAG}/{actor_id}"


def prototypes_of(action: int) -> str:
    """``learner/prototypes/action_<k>``."""
    return f"{LEARNER_PROTOTYPES}/action_{action}"


def part_file(run_dir: Path, process: str) -> Path:
    """Where a process of ``ennc-ql up`` saves its part of the recording: ``<run_dir>/rerun/<process>.rrd``."""
    return run_dir / "rerun" / f"{process}.rrd"
