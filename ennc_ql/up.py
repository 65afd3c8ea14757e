"""``ennc-ql up``: the embedded default cluster on this machine.

One learner and N actor processes (real OS processes, the same commands a multi-machine run uses), joined by
Zenoh in peer mode on a loopback endpoint with multicast scouting off, so nothing leaves the machine and no router
is needed; ``--secure`` joins them through a router instead, each with its own certificate, password and
access-control identity (``ennc-ql secure init``'s files, in ``runs/<id>/secure``); ``--serial`` runs the same
objects in this one process on the in-memory bus. Every actor learns every robot's table (option 2); the learner
averages their changes by visits. The flags are generated from ``tools.cluster.UpConfig`` (with ``up``'s presets,
``UP_PRESETS``); every process's resolved configuration is written into ``runs/<id>/`` (``up.toml``,
``learner.toml``, ``actor-<i>.toml``) and the children start from those files, so ``ennc-ql up --config
runs/<id>/up.toml`` repeats a run exactly. At the end the results are printed and ``runs/<id>/report.md`` and
``learning_curve.png`` are written.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import time
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from actors.config import ActorConfig
from ennc_ql.command import (
    check_device,
    check_folder,
    configure,
    fail,
    make_folder,
    refuse_run,
    registry_choices,
)
from ennc_ql.parser import CommandHelp, add_command
from ennc_ql.report import emit_run_report
from learner.checkpoint import Checkpointer, CheckpointError, policy_problem
from learner.config import LearnerConfig
from learner.report import LearnerReport
from learner.service import LearnerService
from monitor import Sink, add_rerun_args, paths
from protocol import InMemoryBus, InMemoryTransport, check_id
from tools.cluster import (
    SET_BY_UP,
    UP_PRESETS,
    Finished,
    Interruption,
    LaunchError,
    Monitoring,
    ProcessRun,
    RecordingFigures,
    RunReport,
    RunSummary,
    UpConfig,
    child_configs,
    run_serial,
    run_to_report,
    write_configs,
)
from tools.config import ConfigError, add_config_flags, file_path, folder, load_config
from tools.config_fields import config_leaves, flag_name
from tools.system import Interrupts

log = logging.getLogger(__name__)

ACTORS_PER_CORE = 4
"""The most actors up runs per core of this machine: two actors of 500 arenas keep two cores busy, so four to a core
leave each a quarter of one, and each holds up to 300 MB (docs/performance.md, "Memory of the processes")."""

HELP = CommandHelp(
    "up",
    "train on this machine: one learner and N actor processes, then a report (what make run does)",
    "Trains ENNC-QL (collaborative, option 2: every robot learns its own table) on this machine: one learner and "
    "--actors actor processes, real OS processes joined by Zenoh on a loopback endpoint (nothing leaves the "
    "machine), for --duration seconds of training with a progress bar. The learner then scores the final policy on "
    "200 seeded test trials, beside the hand-made controllers on the same trials with the paired difference from "
    "each, and up prints that result. It "
    "writes runs/<id>/: the policy file (policy.npz), the checkpoint, report.md and report.json, "
    "learning_curve.png, policy.png, the Rerun recording of every process (recording.rrd) and one log per process; "
    "up.toml repeats the run exactly. --serial runs the same objects in this one process (for a debugger or a "
    "profiler); --secure joins them through a router with mutual TLS, a password per process and access control. "
    "Ctrl-C, SIGTERM or SIGHUP winds the run down cleanly (the learner checkpoints and scores its policy), writes the "
    "report of the run so far and prints the command that continues it (--resume); a second one kills the actors, a "
    "third the learner, and up always waits for them. Exit status: 0 done, 1 a failure, 2 bad input, 130 Ctrl-C, "
    "143 SIGTERM, 129 SIGHUP.",
    (
        ("ennc-ql up", "the main job, as make run: 2 actors, 120 s of training"),
        ("ennc-ql up --rerun spawn", "the same, watched live in the Rerun viewer"),
        ("ennc-ql up --duration 960", "a 16-minute run: its tables score no better than a 2-minute run's"),
        ("ennc-ql up --config runs/<id>/up.toml", "repeat a run exactly"),
        ("ennc-ql up --resume runs/<id>", "continue a run that was stopped (Ctrl-C, SIGTERM) from its checkpoint"),
    ),
    "--duration (120 s) plus start-up, the final evaluation and the report: about 2.5 min in all with the defaults",
)


def add_up_parser(sub: Any) -> None:
    p = add_command(sub, HELP)
    p.add_argument(
        "--config",
        type=file_path,
        metavar="FILE",
        help="TOML file of up's configuration, e.g. a run's up.toml (default: none)",
    )
    p.add_argument("--serial", action="store_true", help="learner and actors as objects in this one process")
    p.add_argument(
        "--secure",
        action="store_true",
        help="through a router with mutual TLS, a password per process and access control (files in runs/<id>/secure)",
    )
    p.add_argument(
        "--resume",
        type=folder,
        metavar="RUN",
        help="continue the stopped run in folder RUN (runs/<id>) from its checkpoint, with its own configuration "
        "(default: a new run)",
    )
    p.add_argument("--runs", type=folder, metavar="DIR", help="parent folder of the run folder (default: runs)")
    p.add_argument("--run-id", metavar="ID", help="run folder name (default: the start time, YYYYMMDD-HHMMSS)")
    p.add_argument("--json", action="store_true", help="print the learner's report as one JSON object")
    add_config_flags(
        p.add_argument_group("run configuration (tools.cluster.UpConfig)"),
        UpConfig,
        exclude=SET_BY_UP,
        defaults=UP_PRESETS,
        choices=registry_choices(),
    )
    add_rerun_args(p, default=None, default_text="save runs/<id>/recording.rrd")
    p.set_defaults(func=cmd_up)


def cmd_up(args: argparse.Namespace) -> int:
    # Everything is checked here, before any process starts or any folder is made: a bad value is one line naming
    # it, and nothing is left behind.
    if args.resume is not None:
        return _run(args, *check_resume(args), resume=True)
    config: UpConfig = configure(UpConfig, args, "up", defaults=UP_PRESETS)
    check_actors(config.actors)
    if args.serial and args.secure:
        fail("up", "--serial runs on the in-memory bus, which has no network to secure; drop one of them")
    run_id = args.run_id if args.run_id is not None else time.strftime("%Y%m%d-%H%M%S")
    try:
        check_id(run_id, "--run-id")
    except ValueError as exc:
        fail("up", str(exc))
    runs = args.runs or Path("runs")
    run_folder = runs / run_id
    # Only a folder up wrote can be resumed by up: it holds the run's own configuration.
    resume = f"ennc-ql up --resume {run_folder}" if (run_folder / "up.toml").is_file() else None
    refuse_run(run_folder, "up", f"--run-id {run_id}: {run_folder}", resume, another="give a fresh --run-id")
    check_folder(run_folder, "up", "--runs", empty=True)
    check_device(config.learner.phase1.device, "up", "--learner-phase1-device")
    run_dir = make_folder(run_folder, "up", "--runs")
    learner, actors = child_configs(config)
    write_configs(config, learner, actors, run_dir)
    return _run(args, run_dir, config, resume=False)


def _run(args: argparse.Namespace, run_dir: Path, config: UpConfig, *, resume: bool) -> int:
    """The run, fresh or resumed, to its report: the exit status (128 + the signal that stopped it, or 0)."""
    started = time.monotonic()
    # Read before the learner replaces the report: a resumed run's report keeps how it was stopped before.
    earlier = _earlier_interruptions(run_dir) if resume else ()
    interrupts = Interrupts(say=_say)
    # Installed until the report is written: a signal then still counts, and never cuts the report short.
    with interrupts.installed():
        if not args.serial:
            return _processes_and_report(args, config, run_dir, resume, interrupts, started, earlier)
        # One process: no child to kill first; a second signal ends it at once (exit 130, as Ctrl-C does).
        interrupts.escalate(_interrupt_now)
        learner, actors = child_configs(config)
        report = run_serial(learner, actors, run_dir, stop=interrupts.stop)
        summary = _summary(config, run_dir, started, None, secure=False, serial=True, earlier=earlier)
        if interrupts.first is not None:
            stopped = _interruption(interrupts, report, config, run_dir, learner_finished=True)
            summary = dataclasses.replace(summary, interrupted=stopped)
        emit_run_report(report, summary, args.json)
        return interrupts.exit_code


def _interrupt_now() -> str:
    raise KeyboardInterrupt


def _interruption(
    interrupts: Interrupts, report: LearnerReport, config: UpConfig, run_dir: Path, *, learner_finished: bool
) -> Interruption:
    """How a stopped run ended, for its report: the signal, the training time, whether the learner wrote its report
    (else ``up`` made it from the last checkpoint), and the command that continues."""
    assert interrupts.first is not None
    return Interruption(
        signal=interrupts.first.name,
        at_s=round(report.seconds, 1),
        duration_s=config.duration,
        learner="finished" if learner_finished else "killed",
        resume=f"ennc-ql up --resume {run_dir}",
        signals=len(interrupts.received),
    )


def _processes_and_report(
    args: argparse.Namespace,
    config: UpConfig,
    run_dir: Path,
    resume: bool,
    interrupts: Interrupts,
    started: float,
    earlier: tuple[Interruption, ...],
) -> int:
    """The run as OS processes, then its report from what the learner saved, however it ended; ``earlier``: the
    run's interruptions before this resume."""
    learner, actors = child_configs(config)
    report, done = _processes(args, config, learner, actors, run_dir, resume, interrupts)
    signum = interrupts.first
    if report is None:  # stopped before the learner saved anything
        assert signum is not None
        print(
            f"ennc-ql up: interrupted by {signum.name} before the learner saved anything: nothing to report or "
            f"continue; start again with: ennc-ql up --config {run_dir / 'up.toml'}",
            file=sys.stderr,
        )
        return interrupts.exit_code
    secure = _secure(args, run_dir)
    summary = _summary(config, run_dir, started, done.recording, secure=secure, run=done.run, earlier=earlier)
    if signum is not None:
        finished = done.report is not None  # else up made the report from the learner's last checkpoint
        stopped = _interruption(interrupts, report, config, run_dir, learner_finished=finished)
        summary = dataclasses.replace(summary, interrupted=stopped)
    emit_run_report(report, summary, args.json)
    return interrupts.exit_code


def _say(line: str) -> None:
    # From a signal handler: one unbuffered write, never a print that could interrupt another print.
    os.write(2, f"\nennc-ql up: {line}\n".encode())


def _secure(args: argparse.Namespace, run_dir: Path) -> bool:
    return bool(args.secure) or (args.resume is not None and (run_dir / "secure").is_dir())


def _summary(
    config: UpConfig,
    run_dir: Path,
    started: float,
    recording: RecordingFigures | None,
    secure: bool,
    *,
    serial: bool = False,
    run: ProcessRun | None = None,
    earlier: tuple[Interruption, ...] = (),
) -> RunSummary:
    command = f"ennc-ql up --config {run_dir / 'up.toml'}"
    wall_seconds = time.monotonic() - started
    return RunSummary(
        run_dir, command, config, secure, wall_seconds, recording, serial=serial, run=run, earlier=earlier
    )


def _earlier_interruptions(run_dir: Path) -> tuple[Interruption, ...]:
    """The interruptions the run folder's report holds (a resumed run's, from before this resume): the new report
    keeps them, so that a run stopped and resumed says so. A report that cannot be read holds none."""
    try:
        old = RunReport.from_dict(json.loads((run_dir / "report.json").read_text())).launch
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return ()
    if old is None:
        return ()
    return old.interruptions or (() if old.interrupted is None else (old.interrupted,))


def _processes(
    args: argparse.Namespace,
    config: UpConfig,
    learner: LearnerConfig,
    actors: list[ActorConfig],
    run_dir: Path,
    resume: bool,
    interrupts: Interrupts,
) -> tuple[LearnerReport | None, Finished]:
    """The run as OS processes: the learner's report (its own, or built from its checkpoint if it was killed; None
    if it saved nothing), and what its supervision saw with the summary of the merged recording."""
    run_id = run_dir.name
    sink = args.rerun or Sink("save", str(run_dir / paths.RECORDING_FILE))
    if resume and sink.kind == "save" and Path(str(sink.target)).exists():
        # The recording so far is merged with the resumed processes' parts at the end, into one.
        paths.part_file(run_dir, "earlier").parent.mkdir(exist_ok=True)
        Path(str(sink.target)).replace(paths.part_file(run_dir, "earlier"))
    try:
        done = run_to_report(
            learner,
            actors,
            run_dir,
            Monitoring(sink, run_id, run_dir),
            namespace=f"run-{run_id}",
            secure=_secure(args, run_dir),
            resume=resume,
            max_restarts=config.max_restarts,
            interrupts=interrupts,
        )
    except LaunchError as exc:
        fail("up", str(exc))
    if done.report is not None:
        return done.report, done
    saved = saved_report(learner, run_dir)
    if saved is None and interrupts.first is None:
        fail("up", f"the learner wrote no report; see {run_dir / 'learner.log'}")
    return saved, done


def saved_report(learner: LearnerConfig, run_dir: Path) -> LearnerReport | None:
    """The report of what the learner's checkpoint in ``run_dir`` holds (its policy file written from it), for a
    learner killed before it wrote its own; None without a checkpoint."""
    if not Checkpointer(run_dir).path.exists():
        return None
    with InMemoryTransport(InMemoryBus()) as transport:
        try:
            service = LearnerService(transport, learner, run_dir, resume=True)
        except CheckpointError as exc:
            log.error("%s", exc)
            return None
        return service.saved_report()


def check_actors(actors: int) -> None:
    """A number of actors this machine can run (:data:`ACTORS_PER_CORE`), or a one-line error that names the cap."""
    cores = len(os.sched_getaffinity(0))
    most = ACTORS_PER_CORE * cores
    if actors > most:
        fail(
            "up",
            f"--actors {actors}: up runs at most {most} actors on this machine ({ACTORS_PER_CORE} per core, {cores} "
            f"core{'s' if cores > 1 else ''}); for more, spread them over several machines (ennc-ql slurm train, or "
            "ennc-ql actor on each)",
        )


def check_resume(args: argparse.Namespace) -> tuple[Path, UpConfig]:
    """The run folder of ``--resume`` and its configuration, or a one-line error: no flag may change the
    configuration, and there must be a checkpoint with training time left."""
    run_dir: Path = args.resume
    toml = run_dir / "up.toml"
    changes = [flag_name(leaf.path) for leaf in config_leaves(UpConfig) if hasattr(args, leaf.path)]
    changes += [flag for flag, given in _RUN_FLAGS.items() if getattr(args, given)]
    if changes:
        fail(
            "up",
            f"--resume continues {run_dir} with its own configuration ({toml}); {', '.join(changes)} would change it "
            f"(to train differently, start a new run with them: ennc-ql up --config {toml} ...)",
        )
    if not run_dir.is_dir():
        fail("up", f"--resume {run_dir}: no such run folder (give the folder up printed, runs/<id>)")
    if not toml.is_file():
        fail("up", f"--resume {run_dir}: not a run folder of ennc-ql up (no up.toml in it)")
    try:
        config: UpConfig = load_config(UpConfig, file=toml)
    except ConfigError as exc:
        fail("up", f"--resume {run_dir}: {exc}")
    check_actors(config.actors)
    checkpoint = Checkpointer(run_dir).path
    if not checkpoint.is_file():
        fail(
            "up",
            f"--resume {run_dir}: no checkpoint, the run was stopped before its learner saved one; start it again: "
            f"ennc-ql up --config {toml}",
        )
    elapsed = checkpoint_elapsed(checkpoint)
    if elapsed is None:
        fail("up", f"--resume {run_dir}: {checkpoint} is not a checkpoint (not an .npz archive with its figures)")
    problem = policy_problem(checkpoint)
    if problem:
        fail("up", f"--resume {run_dir}: {checkpoint}: {problem}; a run cannot continue from it")
    if elapsed >= config.duration:
        fail(
            "up",
            f"--resume {run_dir}: the run trained its whole {config.duration:g} s already; to train longer, start a "
            f"new run: ennc-ql up --config {toml} --duration {2 * config.duration:g}",
        )
    check_folder(run_dir, "up", "--resume")
    check_device(config.learner.phase1.device, "up", "--learner-phase1-device")
    return run_dir, config


_RUN_FLAGS = {"--config": "config", "--serial": "serial", "--secure": "secure", "--runs": "runs", "--run-id": "run_id"}
"""up's flags that choose a run rather than watch it: ``--resume`` takes them from the run folder."""


def checkpoint_elapsed(path: Path) -> float | None:
    """The training seconds a checkpoint holds, read without loading its arrays; None if it is not one."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(data["meta"].tobytes().decode())
        return float(meta["elapsed"])
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile):
        return None
