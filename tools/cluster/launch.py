"""A run's processes to the learner's report, and what the launcher adds to it: the one path of ``up`` and of a
SLURM job's own side (``ennc-ql slurm run``)::

    done = run_to_report(learner, actors, run_dir, monitoring, namespace=f"run-{run_dir.name}", secure=True)
    summary = RunSummary(run_dir, "ennc-ql up --config runs/x/up.toml", config, secure=True, wall_seconds=480.2,
                         recording=done.recording, run=done.run)
    report = RunReport(done.report, summary.figures(done.report))     # report.json, typed
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from actors.config import ActorConfig
from learner.config import LearnerConfig
from learner.report import LearnerReport
from tools.cluster.config import UpConfig
from tools.cluster.processes import Placement, ProcessRun, run_processes
from tools.cluster.recording import Monitoring
from tools.cluster.report import Interruption, LaunchFigures, RecordingFigures, RunSettings, SlurmFigures
from tools.system import Interrupts

REPORT = "report.json"


@dataclass(frozen=True, slots=True)
class Finished:
    """What :func:`run_to_report` returns."""

    report: LearnerReport | None
    """The report the learner wrote (None if it wrote none: killed, or stopped before it saved anything)."""
    run: ProcessRun
    """What the supervision saw."""
    recording: RecordingFigures | None
    """The figures of the merged recording."""


def run_to_report(
    learner: LearnerConfig,
    actors: list[ActorConfig],
    run_dir: Path,
    monitoring: Monitoring,
    namespace: str,
    secure: bool = False,
    *,
    placement: Placement | None = None,
    resume: bool = False,
    max_restarts: int = 3,
    stop: threading.Event | None = None,
    interrupts: Interrupts | None = None,
    fresh_only: bool = True,
) -> Finished:
    """:func:`~tools.cluster.processes.run_processes` (the same arguments), the recording finished however it ends,
    then the learner's report read from the run folder. ``fresh_only``: a report older than this run is an
    earlier part's (``up --resume``) and is not taken; a SLURM job takes any (a node's clock and its file server's
    may differ). Raises :class:`~tools.cluster.processes.LaunchError` as ``run_processes`` does."""
    begun = time.time()
    try:
        run = run_processes(
            learner,
            actors,
            run_dir,
            monitoring,
            namespace,
            secure,
            placement=placement,
            resume=resume,
            max_restarts=max_restarts,
            stop=stop,
            interrupts=interrupts,
        )
    finally:
        recording = monitoring.finish()
    path = run_dir / REPORT
    written = path.exists() and (not fresh_only or path.stat().st_mtime >= begun)
    report = LearnerReport.from_dict(json.loads(path.read_text())) if written else None
    return Finished(report, run, recording)


@dataclass(frozen=True, slots=True)
class RunSummary:
    """What a launcher adds to the learner's report: which run, the command that runs it again, its configuration,
    how long it took, its recording, what its supervision saw, its SLURM job and how it was interrupted, if it was."""

    run_dir: Path
    command: str
    config: UpConfig
    secure: bool
    wall_seconds: float
    recording: RecordingFigures | None
    serial: bool = False
    run: ProcessRun | None = None
    """The supervision of the processes (none: one process, ``up --serial``)."""
    slurm: SlurmFigures | None = None
    """The job: its id, times requeued, nodes and where each process ran."""
    interrupted: Interruption | None = None
    """The signal that stopped the run, when, and the command that continues it."""
    earlier: tuple[Interruption, ...] = ()
    """The interruptions of the run before this resume (from the report it replaces), oldest first."""

    def figures(self, report: LearnerReport) -> LaunchFigures:
        """The summary as the run report carries it, beside the learner's ``report``."""
        config = self.config
        return LaunchFigures(
            run_id=self.run_dir.name,
            run_dir=str(self.run_dir),
            command=self.command,
            config=RunSettings(
                config.actors, config.duration, config.seed, config.formulation, self.serial, self.secure
            ),
            wall_seconds=round(self.wall_seconds, 1),
            recording=self.recording,
            supervision=None if self.run is None else self.run.supervision(report),
            slurm=self.slurm,
            interrupted=self.interrupted,
            interruptions=(*self.earlier, *([] if self.interrupted is None else [self.interrupted])),
        )
