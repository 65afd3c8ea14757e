"""The Rerun side of a local run: what each child is told, what ``up`` itself starts, and the one recording merged
from the children's part files at the end::

    monitoring = Monitoring(Sink("save", "runs/x/recording.rrd"), run_id="x", run_dir=Path("runs/x"))
    argv += monitoring.child_args("learner-0")    # --rerun save runs/x/rerun/learner-0.rrd --recording-id x
    argv += monitoring.child_args("actor-0", relay=True)   # --rerun learner: the learner logs its rows
    monitoring.start()                            # a viewer (spawn) or a proxy (serve), if asked for
    figures = monitoring.finish()                 # save: the parts merged into recording.rrd, its figures
"""

from __future__ import annotations

import logging
import subprocess
from pathlib import Path

from monitor import Monitor, RecordingError, Sink, merge_recordings, open_monitor, paths, summarize_recording
from monitor.recordings import rerun_cli
from tools.cluster.report import RecordingFigures

log = logging.getLogger(__name__)

VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where a viewer spawned by ``up`` (or its ``rerun --serve-grpc`` proxy) takes the children's streams."""


class Monitoring:
    """``save`` (the default): every child saves its own part file with the run's recording id (processes cannot share
    one file) and the parts are merged into one recording at the end. ``spawn``: ``up`` starts a local viewer and
    the children stream to it. ``serve``: ``up`` starts a ``rerun --serve-grpc`` proxy on port 9876 that viewers on
    this or other machines connect to. ``connect URL``: the children stream to that viewer or proxy.
    """

    def __init__(self, sink: Sink, run_id: str, run_dir: Path) -> None:
        self.sink = sink
        self.run_id = run_id
        self.run_dir = run_dir
        self.viewer: Monitor | None = None
        self.proxy: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        if self.sink.kind == "spawn":
            self.viewer = open_monitor(self.sink, process="up", recording_id=self.run_id)
        elif self.sink.kind == "serve":
            self.proxy = subprocess.Popen(
                [*rerun_cli(), "--serve-grpc", "--port", "9876"],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            log.warning("watch with: rerun --connect rerun+http://<this host>:9876/proxy")

    def child_args(self, name: str, relay: bool = False) -> list[str]:
        """The ``--rerun`` flags of child ``name``; ``relay``: an actor, whose rows the learner logs (it opens no
        recording: docs/performance.md, the actor's memory)."""
        kind = self.sink.kind
        if kind == "off":
            return []
        if relay:
            return ["--rerun", "learner"]
        if kind == "save":
            target = str(paths.part_file(self.run_dir, name))
        else:
            target = str(self.sink.target) if kind == "connect" else VIEWER_URL
        return ["--rerun", "save" if kind == "save" else "connect", target, "--recording-id", self.run_id]

    def finish(self) -> RecordingFigures | None:
        """Merge the part files (``save``) and summarise the recording; stop what ``start`` started."""
        if self.viewer is not None:
            self.viewer.close()
        if self.proxy is not None:
            self.proxy.terminate()
            try:
                self.proxy.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proxy.kill()
                self.proxy.wait()
        if self.sink.kind != "save":
            return None
        parts = sorted((self.run_dir / "rerun").glob("*.rrd"))
        if not parts:
            log.warning("no Rerun part files in %s", self.run_dir / "rerun")
            return None
        try:
            summary = summarize_recording(merge_recordings(parts, Path(str(self.sink.target))))
        except RecordingError as exc:  # the run's results stand without its recording; the parts stay on disk
            log.error("could not merge the Rerun part files %s: %s", [str(p) for p in parts], exc)
            return None
        for part in parts:  # all of it is in the merged recording now
            part.unlink()
        (self.run_dir / "rerun").rmdir()
        return RecordingFigures(
            str(summary["path"]),
            int(summary["size_bytes"]),
            tuple(summary["recording_ids"]),
            tuple(summary["entity_paths"]),
            int(summary["rows"]),
        )
