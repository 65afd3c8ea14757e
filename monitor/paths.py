"""Names shared by every process that logs into the one recording: application id, timelines, entity paths.

Paths are written without a leading ``/``; Rerun treats ``a/b`` and ``/a/b`` alike.

North up: Rerun's 2-D views draw +y downwards, the simulator has north = +y. Each drawing root (an arena origin,
``learner/prototypes/action_<k>``) therefore carries a static transform that mirrors y, and its 2-D view takes the
root's parent as origin so that the transform applies; logged positions stay in arena coordinates.
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
TRAIN_TIME = "train_time"
"""Duration: seconds of training, on every row; the training views' x-axis. The learner's rows carry its run clock
(the clock of the learning curve in ``report.json``, which survives ``--resume``); an actor's rows carry the seconds
since its own loop started, which under ``ennc-ql up`` begins within seconds of the learner's."""
WALL_TIME = "wall_time"
"""Timestamp: seconds since the Unix epoch at the logging process, on every row."""

# -- learner ----------------------------------------------------------------------------------------------------

LEARNER = "learner"
LEARNER_COVERAGE_EVAL = "learner/coverage/eval"
"""Metric A (%) of the current policy on the seeded test trials: the learning curve."""
LEARNER_COVERAGE_FINAL = "learner/coverage/final"
"""Metric A (%) of the final policy on the (more) test trials of the final figure: a marker of its own."""
LEARNER_COVERAGE_REFERENCE = "learner/coverage/reference"
"""Parent of ``learner/coverage/reference/<controller>``: a hand-made controller on the curve's test trials."""
LEARNER_COOPERATION = "learner/cooperation"
"""How the newest evaluated policy's team and the references' spread over the targets: a table (text)."""
LEARNER_TUPLES_PER_S = "learner/tuples_per_s"
LEARNER_POLICY_VERSION = "learner/policy_version"
LEARNER_LIVE_ACTORS = "learner/live_actors"
LEARNER_STORE_SIZE = "learner/store_size"
LEARNER_REJECTED = "learner/rejected"
LEARNER_RSS = "learner/rss_mb"
"""Resident memory of the learner process (MB)."""
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
ACTOR_RSS = "rss_mb"

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

PROTOTYPE_FRAME = "frame"
"""Under ``learner/prototypes/action_<k>``: the static axes and sensing circle the prototypes are read against."""

# -- the colour key ---------------------------------------------------------------------------------------------

KEY = "key"
"""What the colours mean: ``key/{robot,sensing,sensing_disk,observed,unobserved}`` (static) and the Q scale
``key/q/{bar,ends}`` (the ends labelled with the Q range of the latest policy)."""
KEY_Q_BAR = "key/q/bar"
KEY_Q_ENDS = "key/q/ends"

RECORDING_FILE = "recording.rrd"
"""Name of the merged recording in a run folder."""


def actor(actor_id: str, metric: str) -> str:
    """``actors/<actor_id>/<metric>``, e.g. ``actor("actor-0", ACTOR_COVERAGE)``."""
    return f"{ACTORS}/{actor_id}/{metric}"


def actor_arena(actor_id: str) -> str:
    """Root of an actor's arena drawing: ``actors/<actor_id>/arena`` (its view's origin is the parent)."""
    return f"{ACTORS}/{actor_id}/arena"


def learner_lag(actor_id: str) -> str:
    return f"{LEARNER_LAG}/{actor_id}"


def reference(controller: str) -> str:
    """``learner/coverage/reference/<controller>``, e.g. ``reference("a-cmommt")``."""
    return f"{LEARNER_COVERAGE_REFERENCE}/{controller}"


def prototypes_of(action: int) -> str:
    """``learner/prototypes/action_<k>``."""
    return f"{LEARNER_PROTOTYPES}/action_{action}"


def part_file(run_dir: Path, process: str) -> Path:
    """Where a process of ``ennc-ql up`` saves its part of the recording: ``<run_dir>/rerun/<process>.rrd``."""
    return run_dir / "rerun" / f"{process}.rrd"
