"""``ennc-ql up``: the embedded default cluster on this machine.

One learner and N actor processes (real OS processes, the same commands a multi-machine run uses), joined by
Zenoh in peer mode on a loopback endpoint with multicast scouting off, so nothing leaves the machine and no router
is needed; ``--secure`` joins them through a router instead, each with its own certificate, password and
access-control identity (``ennc-ql secure init``'s files, in ``runs/<id>/secure``); ``--serial`` runs the same
objects in this one process on the in-memory bus. Every actor learns every robot's table (option 2); the learner
averages their changes by visits. The flags are generated from ``ennc_ql.cluster.UpConfig`` (with ``up``'s presets,
``UP_PRESETS``); every process's resolved configuration is written into ``runs/<id>/`` (``up.toml``,
``learner.toml``, ``actor-<i>.toml``) and the children start from those files, so ``ennc-ql up --config
runs/<id>/up.toml`` repeats a run exactly. At the end the results are printed and ``runs/<id>/report.md`` and
``learning_curve.png`` are written.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from actors.config import ActorConfig
from algorithm.policy_file import load_policy, scenario_from_header
from ennc_ql.cluster import (
    SET_BY_UP,
    UP_PRESETS,
    LaunchError,
    Monitoring,
    ProcessRun,
    UpConfig,
    child_configs,
    run_processes,
    run_serial,
    write_configs,
)
from ennc_ql.command import check_device, check_folder, configure, emit, fail, make_folder, registry_choices
from ennc_ql.config import add_config_flags
from ennc_ql.figures import policy_figure
from ennc_ql.parser import CommandHelp, add_command
from ennc_ql.report import terminal_summary, write_run_report
from learner.config import LearnerConfig
from learner.report import LearnerReport
from monitor import Sink, add_rerun_args, paths
from protocol import check_id

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
    "profiler); --secure joins them through a router with mutual TLS, a password per process and access control.",
    (
        ("ennc-ql up", "the main job, as make run: 2 actors, 480 s of training"),
        ("ennc-ql up --duration 120 --rerun spawn", "a 2-minute run, watched live in the Rerun viewer"),
        ("ennc-ql up --config runs/<id>/up.toml", "repeat a run exactly"),
    ),
    "--duration (480 s) plus start-up, the final evaluation and the report: about 8 min in all with the defaults",
)


def add_up_parser(sub: Any) -> None:
    p = add_command(sub, HELP)
    p.add_argument(
        "--config", metavar="FILE", help="TOML file of up's configuration, e.g. a run's up.toml (default: none)"
    )
    p.add_argument("--serial", action="store_true", help="learner and actors as objects in this one process")
    p.add_argument(
        "--secure",
        action="store_true",
        help="through a router with mutual TLS, a password per process and access control (files in runs/<id>/secure)",
    )
    p.add_argument("--runs", type=Path, default=Path("runs"), metavar="DIR", help="parent folder of the run folder")
    p.add_argument("--run-id", metavar="ID", help="run folder name (default: the start time, YYYYMMDD-HHMMSS)")
    p.add_argument("--json", action="store_true", help="print the learner's report as one JSON object")
    add_config_flags(
        p.add_argument_group("run configuration (ennc_ql.cluster.UpConfig)"),
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
    config: UpConfig = configure(UpConfig, args, "up", defaults=UP_PRESETS)
    if args.serial and args.secure:
        fail("up", "--serial runs on the in-memory bus, which has no network to secure; drop one of them")
    run_id = args.run_id or time.strftime("%Y%m%d-%H%M%S")
    try:
        check_id(run_id, "--run-id")
    except ValueError as exc:
        fail("up", str(exc))
    check_folder(args.runs / run_id, "up", "--runs", empty=True)
    check_device(config.learner.phase1.device, "up", "--learner-phase1-device")
    run_dir = make_folder(args.runs / run_id, "up", "--runs")
    learner, actors = child_configs(config)
    write_configs(config, learner, actors, run_dir)
    started = time.monotonic()
    supervision: dict[str, Any] = {}
    recording: dict[str, Any] | None = None
    if args.serial:
        report = run_serial(learner, actors, run_dir)
    else:
        report, run, recording = _processes(args, config, learner, actors, run_id)
        supervision = run.report_extra(report)
    extra = {
        "run_id": run_id,
        "run_dir": str(run_dir),
        "command": f"ennc-ql up --config {run_dir / 'up.toml'}",
        "config": {
            "actors": config.actors,
            "duration": config.duration,
            "seed": config.seed,
            "formulation": config.formulation,
            "serial": args.serial,
            "secure": args.secure,
        },
        **supervision,
        "wall_seconds": round(time.monotonic() - started, 1),
        "recording": recording,
    }
    emit_run_report(report, run_dir, extra, args.json)
    return 0


def emit_run_report(report: LearnerReport, run_dir: Path, extra: dict[str, Any], as_json: bool) -> None:
    """The learner's report completed with the launcher's ``extra`` figures and the policy's figure, written as
    ``report.json``, ``report.md`` and ``learning_curve.png``, and printed (``up`` and a SLURM job alike)."""
    out = report.with_extra(**extra, **_policy_figure(report, run_dir)).to_dict()
    markdown, png = write_run_report(out, run_dir)
    out.update(report_md=str(markdown), learning_curve=str(png))
    (run_dir / "report.json").write_text(json.dumps(out, indent=2))
    emit(out, as_json, terminal_summary(out))


def _processes(
    args: argparse.Namespace, config: UpConfig, learner: LearnerConfig, actors: list[ActorConfig], run_id: str
) -> tuple[LearnerReport, ProcessRun, dict[str, Any] | None]:
    """The run as OS processes: the learner's report from the run folder, what its supervision saw and the summary
    of the merged recording."""
    run_dir = args.runs / run_id
    monitoring = Monitoring(args.rerun or Sink("save", str(run_dir / paths.RECORDING_FILE)), run_id, run_dir)
    try:
        run = run_processes(
            learner,
            actors,
            run_dir,
            monitoring,
            namespace=f"run-{run_id}",
            secure=args.secure,
            max_restarts=config.max_restarts,
        )
    except LaunchError as exc:
        fail("up", str(exc))
    finally:
        recording = monitoring.finish()
    report_path = run_dir / "report.json"
    if not report_path.exists():
        fail("up", f"the learner wrote no report; see {run_dir / 'learner.log'}")
    report = LearnerReport.from_dict(json.loads(report_path.read_text()))
    return report, run, recording


def _policy_figure(report: LearnerReport, run_dir: Path) -> dict[str, str]:
    """``policy.png`` of the learned policy, if one was learned."""
    if not report.policy_file:
        return {}
    policy, header = load_policy(report.policy_file)
    return {"policy_figure": str(policy_figure(policy, scenario_from_header(header), run_dir / "policy.png"))}
