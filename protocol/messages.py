"""Typed, versioned wire messages of ENNC-QL.

Every message is a frozen dataclass whose fields carry their wire schema (kind, dtype, symbolic shape) as
field metadata; :func:`validate` checks a message against that schema plus the cross-field rules of its
type. Messages validate themselves on construction, so a message object that exists is a valid one::

    batch = ExperienceBatch(
        actor_id="actor-0", incarnation=0x1234, seq=0, policy_version=0,
        featurizer="collab6d", reward_function="eq2", action_set="compass",
        robot=np.zeros(2, np.int16), state=np.zeros((2, 6), np.float32), action=np.array([1, 7], np.uint8),
        reward=np.zeros(2, np.float32), next_state=np.zeros((2, 6), np.float32), done=np.zeros(2, bool),
    )
    ExperienceBatch(..., reward=np.array([np.nan, 0.0], np.float32))   # raises InvalidValues

Symbols in shapes: N tuples in a batch, d state dimension, P = Σ_a P_a prototypes over all actions,
L = N_ACTIONS actions, R robots. Arrays decoded from the wire are read-only (see ``protocol.codec``).

Over 400 lines: every wire message with its validation, so that the schema reads in one file beside
docs/reference/protocol.md.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType
from typing import Any, ClassVar, Literal, TypeAlias

import numpy as np
import numpy.typing as npt

SCHEMA_VERSION = 2
"""Wire schema version: in the envelope and in every key expression (``enncql/v2/...``)."""

N_ACTIONS = 8
"""L, the number of discrete actions of scenario ``cmommt-v1``; changing it is a schema change."""

ROLES = ("learner", "actor", "evaluator")
MAX_STATE_DIM = 64
MAX_COUNTERS = 64
MAX_NAME_LEN = 64
U64_MAX = 2**64 - 1
INT16_MAX = 2**15 - 1

# Identifiers become key-expression chunks. An allow-list rather than a deny-list keeps them portable and
# excludes everything zenoh treats specially: '/', the wildcards '*' and '**', the DSL characters '$', '?',
# '#', and a leading '@', which makes a chunk verbatim so that wildcards silently stop matching it.
_ID_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")


class ProtocolError(ValueError):
    """Base of every error raised while validating, encoding or decoding a message."""


class MalformedMessage(ProtocolError):
    """Structurally wrong: not msgpack, wrong envelope, unknown type tag, missing or extra fields, wrong
    Python types, array dtypes, ranks or inconsistent lengths."""


class UnexpectedMessageType(MalformedMessage):
    """A well-formed message of another type than the key or the caller expects."""


class SchemaVersionMismatch(ProtocolError):
    """The envelope names a schema version other than :data:`SCHEMA_VERSION`."""


class OversizePayload(ProtocolError):
    """The payload exceeds the size limit (``protocol.codec.MAX_PAYLOAD_BYTES``)."""


class InvalidValues(ProtocolError):
    """Well-formed, but a value is out of its domain: NaN/inf, negative or out-of-range integers, bad
    identifiers or names, unsorted offsets, unknown role, too many counters."""


class IdentityMismatch(ProtocolError):
    """A message claims another sender than the key it travels on: a stream's identity is its key's (an actor's
    experience on ``experience/<actor>`` must say ``actor_id=<actor>``), so no peer can write into another's."""


Kind = Literal["array", "int", "id", "name", "choice", "float", "counters"]


@dataclass(frozen=True, slots=True)
class FieldSpec:
    """Wire schema of one message field (stored in ``dataclasses.field(metadata={"spec": ...})``).

    ``shape`` entries are ints (fixed) or symbols bound consistently across the fields of one message;
    ``lo``/``hi`` bound ints and integer arrays; ``choices`` lists the allowed strings of a ``choice``.
    """

    kind: Kind
    dtype: np.dtype[Any] | None = None
    shape: tuple[int | str, ...] = ()
    lo: int | None = None
    hi: int | None = None
    choices: tuple[str, ...] = ()


def _spec(kind: Kind, **kw: Any) -> dict[str, FieldSpec]:
    return {"spec": FieldSpec(kind, **kw)}


def _array(dtype: str, *shape: int | str, lo: int | None = None, hi: int | None = None) -> dict[str, FieldSpec]:
    return _spec("array", dtype=np.dtype(dtype).newbyteorder("<"), shape=shape, lo=lo, hi=hi)


def _u64(lo: int = 0) -> dict[str, FieldSpec]:
    return _spec("int", lo=lo, hi=U64_MAX)


def field_specs(cls: type[Message]) -> Mapping[str, FieldSpec]:
    """Field name -> :class:`FieldSpec` of message class ``cls``, in wire order."""
    return _FIELD_SPECS[cls]


def check_id(value: object, what: str = "identifier") -> str:
    """Return ``value`` if it is a valid identifier (1–64 of ``[A-Za-z0-9_.-]``, not starting with ``.``
    or ``-``), else raise :class:`InvalidValues` (or :class:`MalformedMessage` if it is not a str)."""
    if not isinstance(value, str):
        raise MalformedMessage(f"{what}: expected str, got {type(value).__name__}")
    if _ID_RE.fullmatch(value) is None:
        raise InvalidValues(f"{what}: {value!r} is not 1-64 characters of [A-Za-z0-9_.-] (first not . or -)")
    return value


def _check_int(name: str, value: object, spec: FieldSpec) -> None:
    # bool is an int subclass in Python, but msgpack true/false is not a number on the wire.
    if not isinstance(value, int) or isinstance(value, bool):
        raise MalformedMessage(f"{name}: expected int, got {type(value).__name__}")
    if (spec.lo is not None and value < spec.lo) or (spec.hi is not None and value > spec.hi):
        raise InvalidValues(f"{name}: {value} outside [{spec.lo}, {spec.hi}]")


def _check_str(name: str, value: object, spec: FieldSpec) -> None:
    if not isinstance(value, str):
        raise MalformedMessage(f"{name}: expected str, got {type(value).__name__}")
    if spec.kind == "id":
        check_id(value, name)
    elif spec.kind == "choice" and value not in spec.choices:
        raise InvalidValues(f"{name}: {value!r} not one of {spec.choices}")
    elif spec.kind == "name" and not (0 < len(value) <= MAX_NAME_LEN and value.isprintable()):
        raise InvalidValues(f"{name}: must be 1-{MAX_NAME_LEN} printable characters")


def _check_array(name: str, value: object, spec: FieldSpec, dims: dict[str, int]) -> None:
    assert spec.dtype is not None
    if not isinstance(value, np.ndarray):
        raise MalformedMessage(f"{name}: expected numpy array, got {type(value).__name__}")
    if value.dtype != spec.dtype:
        raise MalformedMessage(f"{name}: expected dtype {spec.dtype.name}, got {value.dtype}")
    if value.ndim != len(spec.shape):
        raise MalformedMessage(f"{name}: expected {len(spec.shape)}-d array, got shape {value.shape}")
    for size, dim in zip(value.shape, spec.shape, strict=True):
        expected = dims.setdefault(dim, size) if isinstance(dim, str) else dim
        if size != expected:
            raise MalformedMessage(f"{name}: shape {value.shape} inconsistent with {dim}={expected}")
    if value.size == 0:
        return
    kind = spec.dtype.kind
    # min and max propagate NaN and expose ±inf: two read-only passes, no temporary mask of the array's size.
    if kind == "f" and not (math.isfinite(value.min()) and math.isfinite(value.max())):
        raise InvalidValues(f"{name}: contains NaN or infinity")
    if kind == "b" and value.view(np.uint8).max() > 1:
        # Arbitrary wire bytes viewed as bool can hold values other than 0 and 1.
        raise InvalidValues(f"{name}: bool array holds bytes other than 0 and 1")
    if kind in "iu" and (
        (spec.lo is not None and value.min() < spec.lo) or (spec.hi is not None and value.max() > spec.hi)
    ):
        raise InvalidValues(f"{name}: values outside [{spec.lo}, {spec.hi}]")


def _check_float(name: str, value: object) -> None:
    if not isinstance(value, float):
        raise MalformedMessage(f"{name}: expected float, got {type(value).__name__}")
    if not math.isfinite(value):
        raise InvalidValues(f"{name}: {value} is not finite")


def _freeze_counters(value: object) -> Mapping[str, float]:
    if not isinstance(value, Mapping):
        raise MalformedMessage(f"counters: expected a mapping, got {type(value).__name__}")
    if len(value) > MAX_COUNTERS:
        raise InvalidValues(f"counters: {len(value)} entries, at most {MAX_COUNTERS} allowed")
    out: dict[str, float] = {}
    for k, v in value.items():
        if not isinstance(k, str) or not 0 < len(k) <= MAX_NAME_LEN:
            raise InvalidValues(f"counters: key {k!r} is not a str of 1-{MAX_NAME_LEN} characters")
        if not isinstance(v, int | float) or isinstance(v, bool):
            raise MalformedMessage(f"counters[{k!r}]: expected a number, got {type(v).__name__}")
        try:
            number = float(v)
        except OverflowError:  # an int beyond the float range
            number = math.inf
        if not math.isfinite(number):
            raise InvalidValues(f"counters[{k!r}]: {v} is not finite")
        out[k] = number
    return MappingProxyType(out)


def _check_offsets(offsets: npt.NDArray[np.int64], total: int) -> None:
    if offsets[0] != 0 or offsets[-1] != total or (np.diff(offsets) < 0).any():
        raise InvalidValues(f"offsets: must start at 0, be non-decreasing and end at {total}")


def validate(msg: Message) -> None:
    """Check ``msg`` against its schema; raise a :class:`ProtocolError` subclass if it does not conform."""
    dims: dict[str, int] = {}
    for name, spec in field_specs(type(msg)).items():
        value = getattr(msg, name)
        if spec.kind == "array":
            _check_array(name, value, spec, dims)
        elif spec.kind == "int":
            _check_int(name, value, spec)
        elif spec.kind == "float":
            _check_float(name, value)
        elif spec.kind == "counters":
            _freeze_counters(value)
        else:
            _check_str(name, value, spec)
    msg._check_consistency()


def message_equal(a: Message, b: Message) -> bool:
    """Field-wise equality (arrays by dtype, shape and contents); dataclass ``==`` would be ambiguous."""
    if type(a) is not type(b):
        return False
    for name in field_specs(type(a)):
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if not (isinstance(y, np.ndarray) and x.dtype == y.dtype and np.array_equal(x, y)):
                return False
        elif x != y:
            return False
    return True


class _Validated:
    """Mixin: validate on construction; subclasses add cross-field rules in ``_check_consistency``."""

    __slots__ = ()

    def __post_init__(self) -> None:
        validate(self)  # type: ignore[arg-type]

    def validate(self) -> None:
        """Re-check the message; arrays are mutable, so the codec calls this again before encoding."""
        validate(self)  # type: ignore[arg-type]

    def _check_consistency(self) -> None:
        """Cross-field rules beyond shapes and ranges; the default has none."""


@dataclass(frozen=True, slots=True)
class Header:
    """Where a message stands in an actor's stream: the four fields an ``ExperienceBatch`` and a ``QTableIncrement``
    begin with. The actor's outbox makes one per message, with the stream's next seq, and the message is built
    with it (``algorithm.wire``)::

        header = Header(actor_id="actor-0", incarnation=0x1234, seq=5, policy_version=3)
        batch = experience_message(header, transitions)

    A header is never sent as such: on the wire its fields stay flat in the message's body (docs/reference/protocol.md).
    """

    actor_id: str
    incarnation: int
    seq: int
    policy_version: int


@dataclass(frozen=True, slots=True, eq=False)
class ExperienceBatch(_Validated):
    """N experience tuples ⟨robot, s, a, r, s′, done⟩ from one actor, columnar.

    ``(actor_id, incarnation, seq)`` identifies the batch for de-duplication and acknowledgement; the first four
    fields are a :class:`Header`'s.
    """

    TAG: ClassVar[str] = "experience"
    actor_id: str = field(metadata=_spec("id"))
    # u64 drawn at random at each actor process start.
    incarnation: int = field(metadata=_u64())
    # u64 message counter of the incarnation from 0, shared with QTableIncrement.seq.
    seq: int = field(metadata=_u64())
    # PolicyUpdate.version the tuples were collected with; 0 = random exploration.
    policy_version: int = field(metadata=_u64())
    # The formulation the tuples were made under, as in PolicyUpdate: the state definition (its dimension is d),
    # the reward function and the action set, each a name in identifier syntax. The learner refuses a batch whose
    # formulation is not its own: its tuples would mean something else.
    featurizer: str = field(metadata=_spec("id"))
    reward_function: str = field(metadata=_spec("id"))
    action_set: str = field(metadata=_spec("id"))
    # [N] int16 robot id of each tuple, ≥ 0.
    robot: npt.NDArray[np.int16] = field(metadata=_array("int16", "N", lo=0))
    # [N, d] float32 featurized state s (units of the featurizer).
    state: npt.NDArray[np.float32] = field(metadata=_array("float32", "N", "d"))
    # [N] uint8 action index a < L.
    action: npt.NDArray[np.uint8] = field(metadata=_array("uint8", "N", hi=N_ACTIONS - 1))
    # [N] float32 reward r.
    reward: npt.NDArray[np.float32] = field(metadata=_array("float32", "N"))
    # [N, d] float32 featurized next state s′.
    next_state: npt.NDArray[np.float32] = field(metadata=_array("float32", "N", "d"))
    # [N] bool: the episode ended at s′.
    done: npt.NDArray[np.bool_] = field(metadata=_array("bool", "N"))

    def _check_consistency(self) -> None:
        if not 1 <= self.state.shape[1] <= MAX_STATE_DIM:
            raise MalformedMessage(f"state: dimension d={self.state.shape[1]} outside [1, {MAX_STATE_DIM}]")

    @property
    def n_tuples(self) -> int:
        """N (a property, not ``__len__``: an empty batch must not be falsy)."""
        return int(self.robot.shape[0])


@dataclass(frozen=True, slots=True, eq=False)
class QTableIncrement(_Validated):
    """One robot's Q-table delta over discretization ``policy_version``, sent by the actor hosting it; the first four
    fields are a :class:`Header`'s.

    The table is the concatenation over actions a = 0..L-1 of its P_a prototype cells:
    cells of action a are ``q[offsets[a]:offsets[a + 1]]``.
    """

    TAG: ClassVar[str] = "qinc"
    actor_id: str = field(metadata=_spec("id"))
    incarnation: int = field(metadata=_u64())
    # Same counter as ExperienceBatch.seq of this incarnation.
    seq: int = field(metadata=_u64())
    # The PolicyUpdate.version whose prototypes the cells refer to.
    policy_version: int = field(metadata=_u64())
    # Robot id, 0..32767.
    robot: int = field(metadata=_spec("int", lo=0, hi=INT16_MAX))
    # [P] float32 change of each cell's Q value since the actor's previous increment for this robot.
    q: npt.NDArray[np.float32] = field(metadata=_array("float32", "P"))
    # [P] uint32 visits per cell since the actor's previous increment for this robot.
    visits: npt.NDArray[np.uint32] = field(metadata=_array("uint32", "P"))
    # [L+1] int64: cells of action a are offsets[a]:offsets[a+1]; 0 first, non-decreasing, P last.
    offsets: npt.NDArray[np.int64] = field(metadata=_array("int64", N_ACTIONS + 1))

    def _check_consistency(self) -> None:
        _check_offsets(self.offsets, self.q.shape[0])


@dataclass(frozen=True, slots=True, eq=False)
class PolicyUpdate(_Validated):
    """The learner's current policy: per-action prototypes with their labels, and per-robot Q tables.

    Prototypes of action a are rows ``offsets[a]:offsets[a + 1]`` of ``prototypes``; column j of
    ``q_tables``/``visits`` is the same cell as row j of ``prototypes``.
    """

    TAG: ClassVar[str] = "policy"
    # u64 ≥ 1, strictly increasing over the learner's life, across restarts.
    version: int = field(metadata=_u64(lo=1))
    # Versioned scenario name, e.g. "cmommt-v1".
    scenario: str = field(metadata=_spec("name"))
    # The formulation the policy is learned under, each a name in identifier syntax: the state definition (e.g.
    # "shared8d", whose dimension is d), the reward function (e.g. "difference") and the action set (e.g. "compass").
    # Which names exist is the processes' business (sim's registries): an actor refuses a policy over another
    # formulation than its own.
    featurizer: str = field(metadata=_spec("id"))
    reward_function: str = field(metadata=_spec("id"))
    action_set: str = field(metadata=_spec("id"))
    # Simulator steps an action is held, ≥ 1.
    action_steps: int = field(metadata=_spec("int", lo=1, hi=2**31 - 1))
    # [P, d] float32 prototype states.
    prototypes: npt.NDArray[np.float32] = field(metadata=_array("float32", "P", "d"))
    # [P] float32 phase-1 label (Q value) of each prototype.
    labels: npt.NDArray[np.float32] = field(metadata=_array("float32", "P"))
    # [L+1] int64: prototypes of action a are rows offsets[a]:offsets[a+1].
    offsets: npt.NDArray[np.int64] = field(metadata=_array("int64", N_ACTIONS + 1))
    # [R] int16 distinct robot ids, ≥ 0.
    robots: npt.NDArray[np.int16] = field(metadata=_array("int16", "R", lo=0))
    # [R, P] float32 merged Q table of robot robots[i] in row i.
    q_tables: npt.NDArray[np.float32] = field(metadata=_array("float32", "R", "P"))
    # [R, P] uint32 merged visit counts.
    visits: npt.NDArray[np.uint32] = field(metadata=_array("uint32", "R", "P"))
    # [d] float32 > 0: a state's cell is its nearest prototype under |(x − c) / scale| (all ones = Euclidean).
    scale: npt.NDArray[np.float32] = field(metadata=_array("float32", "d"))

    def _check_consistency(self) -> None:
        if not 1 <= self.prototypes.shape[1] <= MAX_STATE_DIM:
            raise MalformedMessage(f"prototypes: dimension d={self.prototypes.shape[1]} outside [1, {MAX_STATE_DIM}]")
        if not (self.scale > 0).all():
            raise InvalidValues("scale: every component must be positive")
        _check_offsets(self.offsets, self.prototypes.shape[0])
        if np.unique(self.robots).size != self.robots.size:
            raise InvalidValues("robots: ids must be distinct")

    @property
    def n_prototypes(self) -> int:
        """P = Σ_a P_a."""
        return int(self.prototypes.shape[0])


@dataclass(frozen=True, slots=True, eq=False)
class Ack(_Validated):
    """Cumulative acknowledgement, learner → actor: every seq ≤ ``seq`` of this incarnation is stored."""

    TAG: ClassVar[str] = "ack"
    actor_id: str = field(metadata=_spec("id"))
    incarnation: int = field(metadata=_u64())
    seq: int = field(metadata=_u64())


@dataclass(frozen=True, slots=True, eq=False)
class Reject(_Validated):
    """Negative acknowledgement, learner → actor: the message ``seq`` of this incarnation was refused for good (it
    will be refused again if re-sent); the sender drops it from its outbox, and the cumulative ack steps over it."""

    TAG: ClassVar[str] = "reject"
    actor_id: str = field(metadata=_spec("id"))
    incarnation: int = field(metadata=_u64())
    seq: int = field(metadata=_u64())
    # Why, e.g. "InvalidValues: reward: NaN or inf" (1-64 printable characters).
    reason: str = field(metadata=_spec("name"))


@dataclass(frozen=True, slots=True, eq=False)
class Status(_Validated):
    """Periodic health and metrics of any process; best effort (DROP QoS), never needed for correctness.

    ``counters`` is copied into a read-only mapping of str (1–64 chars) to finite float, ≤ 64 entries.
    """

    TAG: ClassVar[str] = "status"
    sender: str = field(metadata=_spec("id"))
    # "learner", "actor" or "evaluator".
    role: str = field(metadata=_spec("choice", choices=ROLES))
    # Seconds since the Unix epoch at the sender.
    wall_time: float = field(metadata=_spec("float"))
    # Metric name -> value, e.g. {"tuples_per_s": 1.2e6}.
    counters: Mapping[str, float] = field(metadata=_spec("counters"))

    def __post_init__(self) -> None:
        object.__setattr__(self, "counters", _freeze_counters(self.counters))
        validate(self)


MAX_VIEW_FRAMES = 1000
"""T, the most arena frames one ActorView carries (a learning trial is 100 steps)."""
MAX_VIEW_ENTITIES = 256
"""The most robots, and the most targets, one ActorView frame carries."""
VIEW_COUNTERS = ("coverage", "reward", "tuples_per_s", "policy_version", "rss_mb")
"""The figures an ActorView may carry: the viewer's ``actors/<id>/<name>`` series (``monitor.paths``)."""


@dataclass(frozen=True, slots=True, eq=False)
class ActorView(_Validated):
    """What an actor shows in the viewer, relayed by the learner into its recording (``--rerun learner``), so that
    the actor itself opens no recording: its figures after a learning trial and, for a sampled trial, arena 0 at
    each of its steps. Best effort (DROP QoS), never needed for correctness.
    """

    TAG: ClassVar[str] = "view"
    actor_id: str = field(metadata=_spec("id"))
    # The actor's sim_step timeline at the end of the trial, and its train_time there (seconds since its loop began).
    sim_step: int = field(metadata=_u64())
    train_time: float = field(metadata=_spec("float"))
    # Seconds since the Unix epoch at the sender, at the end of the trial.
    wall_time: float = field(metadata=_spec("float"))
    # The trial's figures by name, each of VIEW_COUNTERS at most once, any of them left out.
    counters: Mapping[str, float] = field(metadata=_spec("counters"))
    # [T] uint64 sim_step of each arena frame; T = 0 for a trial not drawn, ≤ MAX_VIEW_FRAMES.
    frame_step: npt.NDArray[np.uint64] = field(metadata=_array("uint64", "T"))
    # [T] float64 the actor's train_time at each frame, ≥ 0.
    frame_time: npt.NDArray[np.float64] = field(metadata=_array("float64", "T"))
    # [T, m, 2] float32 robot positions, [T, n, 2] float32 target positions (arena units); m, n ≤ MAX_VIEW_ENTITIES.
    robot_pos: npt.NDArray[np.float32] = field(metadata=_array("float32", "T", "m", 2))
    target_pos: npt.NDArray[np.float32] = field(metadata=_array("float32", "T", "n", 2))
    # Sensing range and arena radius the frames are drawn with, > 0.
    sensing_range: float = field(metadata=_spec("float"))
    arena_radius: float = field(metadata=_spec("float"))

    def __post_init__(self) -> None:
        object.__setattr__(self, "counters", _freeze_counters(self.counters))
        validate(self)

    def _check_consistency(self) -> None:
        frames, robots, targets = self.robot_pos.shape[0], self.robot_pos.shape[1], self.target_pos.shape[1]
        if frames > MAX_VIEW_FRAMES:
            raise InvalidValues(f"robot_pos: {frames} frames, at most {MAX_VIEW_FRAMES} allowed")
        if robots > MAX_VIEW_ENTITIES or targets > MAX_VIEW_ENTITIES:
            raise InvalidValues(f"{robots} robots and {targets} targets per frame, at most {MAX_VIEW_ENTITIES} each")
        if self.train_time < 0 or (self.frame_time < 0).any():
            raise InvalidValues("train_time, frame_time: seconds since the actor's loop began, never negative")
        if self.sensing_range <= 0 or self.arena_radius <= 0:
            raise InvalidValues("sensing_range, arena_radius: must be positive")
        unknown = sorted(set(self.counters) - set(VIEW_COUNTERS))
        if unknown:
            raise InvalidValues(f"counters: {unknown} not among {VIEW_COUNTERS}")


Message: TypeAlias = ExperienceBatch | QTableIncrement | PolicyUpdate | Ack | Reject | Status | ActorView

MESSAGE_TYPES: Mapping[str, type[Message]] = MappingProxyType(
    {cls.TAG: cls for cls in (ExperienceBatch, QTableIncrement, PolicyUpdate, Ack, Reject, Status, ActorView)}
)
"""Type tag on the wire -> message class."""

# Precomputed: dataclasses.fields() is slow enough to show in the codec's profile.
_FIELD_SPECS: Mapping[type[Message], Mapping[str, FieldSpec]] = {
    cls: MappingProxyType({f.name: f.metadata["spec"] for f in fields(cls)}) for cls in MESSAGE_TYPES.values()
}
