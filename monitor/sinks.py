"""Choosing where a process's monitoring goes: the ``--rerun`` / ``--recording-id`` flags and :func:`open_monitor`."""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import socket
import sys
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast, get_args
from urllib.parse import urlsplit

from monitor.interface import Monitor
from monitor.paths import APPLICATION_ID

log = logging.getLogger(__name__)

SinkKind = Literal["off", "save", "spawn", "connect", "serve", "learner"]
SINK_KINDS: tuple[str, ...] = get_args(SinkKind)
_NEEDS_TARGET = {"save": "a path to an .rrd file", "connect": "a URL like rerun+http://127.0.0.1:9876/proxy"}
_URL_SCHEMES = ("rerun", "rerun+http", "rerun+https")


VIEWER_PORT = 9876
"""Where a viewer that ``spawn`` starts (or finds running) takes recordings."""


def viewer_executable() -> str | None:
    """The Rerun viewer to spawn: the one rerun-sdk installed beside this interpreter (a venv's ``bin/rerun``,
    found without the venv on PATH, and of the SDK's own version), else ``rerun`` on PATH; None if neither."""
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() else shutil.which("rerun")


def has_display() -> bool:
    """Whether a viewer's window can open here: not Linux, or a Linux session with an X or Wayland display."""
    return not sys.platform.startswith("linux") or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


WEB_VIEWER = "rerun --serve-web --bind 127.0.0.1"
"""How a recording is watched where there is no display: Rerun's web viewer on http://127.0.0.1:9090 (its page) and
gRPC on 127.0.0.1:9876 (the recording), both on loopback only (``--bind``: Rerun listens on every interface
without it)."""
WEB_VIEWER_WHY = (
    "no display here: serve it to a browser at http://127.0.0.1:9090 (loopback only; from another machine first "
    "ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876 to this one)"
)


def spawn_problem(port: int = VIEWER_PORT) -> str | None:
    """Why ``--rerun spawn`` cannot show a viewer here, or None: checked before anything starts."""
    with socket.socket() as probe:
        probe.settimeout(0.5)
        if probe.connect_ex(("127.0.0.1", port)) == 0:
            return None  # a viewer (or a rerun --serve-web) runs already: spawn streams to it
    if viewer_executable() is None:
        return "no Rerun viewer here (rerun-sdk installs `rerun` beside python; pip install rerun-sdk)"
    if not has_display():
        return (
            "no display for the viewer's window here (DISPLAY and WAYLAND_DISPLAY are unset); record instead "
            "(--rerun save FILE.rrd, ennc-ql up's default) and open it with rerun FILE.rrd where there is a screen, "
            f"or serve it to a browser on this machine's loopback: {WEB_VIEWER} FILE.rrd (http://127.0.0.1:9090)"
        )
    return None


def serve_problem(port: int = VIEWER_PORT) -> str | None:
    """Why ``--rerun serve`` cannot listen on ``port`` here, or None: Rerun's server logs a taken port and goes on
    serving nothing, so it is checked before anything starts."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("0.0.0.0", port))
        except OSError as exc:
            return (
                f"port {port} is taken ({exc.strerror or exc}): a viewer or another --rerun serve listens there; "
                f"stream to it with --rerun connect rerun+http://127.0.0.1:{port}/proxy, or stop it"
            )
    return None


def _check(kind: str, target: str | None) -> None:
    if kind not in SINK_KINDS:
        raise ValueError(f"unknown Rerun sink {kind!r}; choose one of {', '.join(SINK_KINDS)}")
    if kind in _NEEDS_TARGET:
        if not target:
            raise ValueError(f"'{kind}' needs {_NEEDS_TARGET[kind]}")
    elif target is not None:
        raise ValueError(f"'{kind}' takes no argument, got {target!r}")
    if kind == "connect" and target is not None:
        url = urlsplit(target)
        if url.scheme not in _URL_SCHEMES or not url.hostname or url.path != "/proxy":
            raise ValueError(
                f"'connect' needs a URL like rerun+http://127.0.0.1:9876/proxy (scheme "
                f"{', '.join(s + '://' for s in _URL_SCHEMES)} and path /proxy), got {target!r}"
            )


@dataclass(frozen=True, slots=True)
class Sink:
    """Where a recording stream sends its data.

    ``off`` (nothing, no Rerun import), ``save`` to the .rrd file ``target``, ``spawn`` a local viewer (or join the
    one already listening on port 9876), ``connect`` to the gRPC URL ``target`` of a viewer or a ``rerun --serve-grpc``
    server, ``serve`` a gRPC server on port 9876 that viewers connect to (one per host: the port is fixed);
    ``learner``, an actor's only: its rows travel to the learner, which logs them wherever its own go
    (:class:`monitor.relay.RelayMonitor`; no Rerun in the actor).
    """

    kind: SinkKind = "off"
    target: str | None = None

    def __post_init__(self) -> None:
        _check(self.kind, self.target)

    @classmethod
    def parse(cls, words: Sequence[str]) -> Sink:
        """``["save", "run.rrd"]`` -> ``Sink("save", "run.rrd")``; raises ValueError with the reason."""
        if not 1 <= len(words) <= 2:
            raise ValueError(f"expected a sink and at most one argument, got {' '.join(words)!r}")
        return cls(cast(SinkKind, words[0]), words[1] if len(words) == 2 else None)


class _SinkAction(argparse.Action):
    """Parses ``--rerun KIND [TARGET]`` into a :class:`Sink` at parse time, so a bad value is an argparse error."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: str | Sequence[Any] | None,
        option_string: str | None = None,
    ) -> None:
        words = [values] if isinstance(values, str) else [str(v) for v in values or []]
        try:
            sink = Sink.parse(words)
        except ValueError as exc:
            parser.error(f"{option_string}: {exc}")
        setattr(namespace, self.dest, sink)


def add_rerun_args(
    parser: argparse.ArgumentParser, default: Sink | None = Sink(), default_text: str = "off", relay: bool = False
) -> None:
    """Add ``--rerun off|save PATH|spawn|connect URL|serve`` (and ``learner`` with ``relay``: an actor's) and
    ``--recording-id ID``.

    ``default`` is what ``--rerun`` holds when not given (``None`` lets the command choose, e.g. a path inside the
    run folder it creates), described in the help as ``default_text``.
    """
    relayed = " | learner (the learner logs this actor's rows)" if relay else ""
    group = parser.add_argument_group("monitoring (Rerun)")
    group.add_argument(
        "--rerun",
        nargs="+",
        action=_SinkAction,
        default=default,
        metavar="SINK",
        help=(
            f"off | save PATH | spawn | connect URL (rerun+http://HOST:9876/proxy) | serve{relayed} (default: "
            f"{default_text})"
        ),
    )
    group.add_argument(
        "--recording-id",
        type=_recording_id,
        default=None,
        metavar="ID",
        help="Rerun recording id shared by every process of a run (default: a fresh one)",
    )


def _recording_id(text: str) -> str:
    """A recording id is a name the viewer groups every process's rows by: an empty one would group nothing."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a recording id, got an empty value")
    return text


def sink_from_args(args: argparse.Namespace) -> Sink:
    """The sink parsed by :func:`add_rerun_args`."""
    sink: Sink = args.rerun
    return sink


def open_monitor(
    sink: Sink,
    *,
    process: str,
    recording_id: str | None = None,
    application_id: str = APPLICATION_ID,
) -> Monitor:
    """A monitor for ``process`` (a name for logs, e.g. ``"learner"``, ``"actor-0"``) logging to ``sink``.

    ``off`` gives the no-op :class:`Monitor` without importing Rerun. Otherwise a
    ``RecordingStream(application_id, recording_id=...)`` with its sink set; processes that pass the same
    ``recording_id`` log into one recording (``None``: a fresh id, logged).
    """
    if sink.kind == "off":
        return Monitor()
    if sink.kind == "learner":
        raise ValueError(f"{process}: --rerun learner is an actor's (its rows travel to the learner): use RelayMonitor")
    # Imported here so that monitoring off never loads Rerun (or matplotlib) into the process.
    import rerun as rr

    from monitor.rerun_monitor import RerunMonitor

    if recording_id is None:
        recording_id = str(uuid.uuid4())
        log.info("%s: new Rerun recording id %s", process, recording_id)
    rec = rr.RecordingStream(application_id, recording_id=recording_id)
    if sink.kind == "save":
        path = Path(str(sink.target))
        path.parent.mkdir(parents=True, exist_ok=True)
        rec.save(path)
        log.info("%s: saving the Rerun recording to %s", process, path)
    elif sink.kind == "spawn":
        rr.spawn(port=VIEWER_PORT, executable_path=viewer_executable(), recording=rec)
        log.info("%s: streaming to a local Rerun viewer (spawned, or the one already on port 9876)", process)
    elif sink.kind == "connect":
        rec.connect_grpc(sink.target)
        log.info("%s: streaming to the Rerun viewer at %s", process, sink.target)
    else:
        url = rec.serve_grpc()
        log.info("%s: serving the Rerun recording at %s (open it with: rerun %s)", process, url, url)
    return RerunMonitor(rec, process)
