"""``report.json``, typed from the run's end to ``report.md``: the learner's report
(:class:`learner.report.LearnerReport`) and what the launcher adds to it (:class:`LaunchFigures`: which run, its
command and settings, its recording, what its supervision saw, its SLURM job, how it was stopped), held together as
one :class:`RunReport`, which the run report's writers read by attribute::

    report = RunReport(learner_report, summary.figures(learner_report))   # the end of up or of a SLURM job
    report.to_dict()                                                       # report.json: flat, its keys as before
    RunReport.from_dict(json.loads(path.read_text()))                      # and back (a resumed run's, a test's)

A reader is lenient where ``report.json`` files of earlier versions lack a figure (it takes the field's default)
and strict where a figure has the wrong shape (a TypeError or KeyError names it).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar

from learner.report import LearnerReport

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class RunSettings:
    """The run's settings that its report repeats (``report.json``'s ``config``)."""

    actors: int
    duration: float
    """Seconds of training the run was given."""
    seed: int = 0
    formulation: str = ""
    serial: bool = False
    """One process on the in-memory bus (``up --serial``)."""
    secure: bool = False
    """Through a router with mutual TLS (``up --secure``, a SLURM job by default)."""


@dataclass(frozen=True, slots=True)
class RecordingFigures:
    """The merged Rerun recording of the run (``monitor.recordings.summarize_recording``'s figures)."""

    path: str
    size_bytes: int = 0
    recording_ids: tuple[str, ...] = ()
    entity_paths: tuple[str, ...] = ()
    rows: int = 0


@dataclass(frozen=True, slots=True)
class LearnerRestart:
    """One restart of the learner under supervision."""

    status: int
    """The exit status of the incarnation that ended (-9: SIGKILL)."""
    ran_s: float
    delay_s: float
    """Back-off before the next incarnation started."""
    back_in_s: float | None
    """Seconds from its end being noticed to the resumed learner's first broadcast (None: it never came)."""


@dataclass(frozen=True, slots=True)
class PolicyVersions:
    """The policy versions seen on the wire, in arrival order."""

    seen: int
    first: int | None
    last: int | None
    increasing: bool
    """Every version above the one before it."""


@dataclass(frozen=True, slots=True)
class Supervision:
    """What the supervision of the run's processes saw (``tools.cluster.processes.ProcessRun``)."""

    endpoint: str
    actor_restarts: dict[str, int]
    """Restarts of each child but the learner (the router's included)."""
    learner_restarts: tuple[LearnerRestart, ...]
    actors_sent: dict[str, dict[str, int]]
    """Per actor: incarnations, how many reported at their end, and the tuples those sent and had acknowledged."""
    first_policy_s: float | None
    """Seconds from the start to the first policy seen on the wire."""
    policy_versions: PolicyVersions


@dataclass(frozen=True, slots=True)
class SlurmFigures:
    """The SLURM job a run ran as."""

    job_id: str
    requeued: int
    """Times the job was requeued (each resumed from the checkpoint)."""
    nodes: tuple[str, ...]
    placement: dict[str, str]
    """The node each process ran on, by process id."""


@dataclass(frozen=True, slots=True)
class Interruption:
    """A signal that stopped the run."""

    signal: str
    """The first signal's name: SIGINT, SIGTERM or SIGHUP."""
    at_s: float
    """Seconds of training when the learner stopped."""
    duration_s: float
    """Seconds of training the run was given."""
    learner: Literal["finished", "killed"]
    """The learner wrote its report (``finished``), or it was killed and the report is its last checkpoint's."""
    resume: str
    """The command that continues the run."""
    signals: int = 1
    """Signals received in all (a second kills the actors, a third the learner)."""


@dataclass(frozen=True, slots=True)
class LaunchFigures:
    """What a launcher (``ennc-ql up``, a SLURM job) adds to the learner's report."""

    run_id: str
    run_dir: str
    command: str
    """The command that runs it again."""
    config: RunSettings
    wall_seconds: float = 0.0
    """Seconds from the launcher's start to the report, start-up and wind-down included."""
    recording: RecordingFigures | None = None
    supervision: Supervision | None = None
    """None: one process (``up --serial``)."""
    slurm: SlurmFigures | None = None
    interrupted: Interruption | None = None
    """How this part of the run was stopped (None: it ran its course)."""
    interruptions: tuple[Interruption, ...] = ()
    """Every stop of the run, resumed ones first, this part's last."""

    def to_dict(self) -> dict[str, Any]:
        """``report.json``'s launcher keys: the supervision's figures at the top level, the optional ones only when
        there."""
        out = {name: to_json(getattr(self, name)) for name in _FLAT}
        if self.supervision is not None:
            out.update(to_json(self.supervision))
        if self.slurm is not None:
            out["slurm"] = to_json(self.slurm)
        if self.interrupted is not None:
            out["interrupted"] = to_json(self.interrupted)
        if self.interruptions:
            out["interruptions"] = to_json(self.interruptions)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LaunchFigures:
        flat = {key: data[key] for key in (*_FLAT, "slurm", "interrupted", "interruptions") if key in data}
        if "endpoint" in data:
            flat["supervision"] = {f.name: data[f.name] for f in dataclasses.fields(Supervision) if f.name in data}
        return from_json(cls, flat)


_FLAT = ("run_id", "run_dir", "command", "config", "wall_seconds", "recording")


@dataclass(frozen=True, slots=True)
class RunReport:
    """``report.json``: the learner's report, the launcher's figures beside it and the files written from them."""

    learner: LearnerReport
    launch: LaunchFigures | None = None
    """None: the learner's report alone (a learner started by hand)."""
    policy_figure: str | None = None
    """``policy.png`` of the saved policy, once drawn."""
    report_md: str | None = None
    learning_curve: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out = self.learner.to_dict()
        if self.launch is not None:
            out.update(self.launch.to_dict())
        for name in ("policy_figure", "report_md", "learning_curve"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunReport:
        def path(name: str) -> str | None:
            return None if data.get(name) is None else str(data[name])

        launch = LaunchFigures.from_dict(data) if "run_id" in data else None
        learner = LearnerReport.from_dict(data)
        return cls(learner, launch, path("policy_figure"), path("report_md"), path("learning_curve"))

    @property
    def run_dir(self) -> Path:
        """The run folder: the launcher's, or the folder of the learner's checkpoint."""
        if self.launch is not None:
            return Path(self.launch.run_dir)
        return Path(self.learner.checkpoint).parent


def to_json(value: Any) -> Any:
    """A typed record as JSON's values: dataclasses as objects, tuples as arrays."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_json(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple | list):
        return [to_json(v) for v in value]
    if isinstance(value, dict):
        return {k: to_json(v) for k, v in value.items()}
    return value


def from_json(kind: type[T], value: Any) -> T:
    """``value`` (JSON's) as ``kind``: a dataclass from an object by its fields' types (a field left out takes its
    default), containers item by item."""
    return typing.cast(T, _convert(kind, value))


def _convert(kind: Any, value: Any) -> Any:
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _convert(inner, value)
    if origin is Literal:
        if value not in args:
            raise TypeError(f"expected one of {args}, got {value!r}")
        return value
    if origin is tuple:
        return tuple(_convert(args[0], v) for v in value)
    if origin is dict:
        return {str(k): _convert(args[1], v) for k, v in value.items()}
    if isinstance(kind, type) and dataclasses.is_dataclass(kind):
        if not isinstance(value, Mapping):
            raise TypeError(f"{kind.__name__}: expected an object, got {value!r}")
        hints = typing.get_type_hints(kind)
        given = {f.name: _convert(hints[f.name], value[f.name]) for f in dataclasses.fields(kind) if f.name in value}
        return kind(**given)
    if kind is float:
        return float(value)
    if kind in (int, str, bool) and not isinstance(value, kind):
        raise TypeError(f"expected {kind.__name__}, got {value!r}")
    return value
