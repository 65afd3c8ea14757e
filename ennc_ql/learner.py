"""``ennc-ql learner``: the central learner as one process, on a Zenoh session chosen by the shared flags.

The flags are generated from ``learner.config.LearnerConfig`` (the field docstrings are the ``--help`` text),
``--config FILE`` reads the same fields from TOML, and flags given override the file. SIGTERM / SIGINT stop it
cleanly: it checkpoints and writes its report. Usage::

    ennc-ql learner --listen tcp/0.0.0.0:7447 --run-dir runs/exp1 --duration 600
    ennc-ql learner --config runs/exp1/learner.toml --run-dir runs/exp1 --listen tcp/0.0.0.0:7447
    ennc-ql learner --run-dir runs/exp1 --resume auto ...   # under a restart policy: resume if a checkpoint exists
"""

from __future__ import annotations

import argparse
import zipfile
from pathlib import Path
from typing import Any

from ennc_ql.command import (
    TRAINED,
    add_process_args,
    check_device,
    check_folder,
    checked_zenoh,
    configure,
    emit,
    fail,
    make_folder,
    open_transport,
    refuse_run,
    registry_choices,
)
from ennc_ql.parser import CommandHelp, add_command
from learner.checkpoint import Checkpointer, CheckpointError, policy_problem
from learner.config import LearnerConfig
from learner.service import LearnerService
from learner.wiring import connect
from monitor import open_monitor, sink_from_args
from tools.config import folder
from tools.system import stop_on_signals

HELP = CommandHelp(
    "learner",
    "the central ENNC-QL learner process, for runs over several machines",
    "The central learner: it stores the actors' experience, runs ENNC-QL phase 1 once --min-tuples are in, merges "
    "the actors' Q-table changes, broadcasts a policy with a strictly increasing version every few seconds, "
    "evaluates it on seeded development trials (the learning curve), checkpoints (acknowledging only what a "
    "checkpoint holds) and, at the end, saves its last policy (a law action set's read with the law margin that "
    "scores best on validation trials of their own seed), scores it on the reported test trials beside every "
    "hand-made reference and writes report.json and policy.npz into --run-dir. It runs "
    "until --duration or SIGTERM/Ctrl-C, which end it cleanly. --resume continues from the checkpoint in --run-dir "
    "after a crash. ennc-ql up starts one of these for you; start it by hand for several machines.",
    (
        ("ennc-ql learner --listen tcp/0.0.0.0:7447 --run-dir runs/exp1 --duration 600", "listen for actors"),
        ("ennc-ql learner --mode client --connect tcp/ROUTER:7447 --run-dir runs/exp1", "join through a router"),
        ("ennc-ql learner --run-dir runs/exp1 --resume --listen tcp/0.0.0.0:7447", "continue after a crash"),
    ),
    "until --duration or a signal; start-up about 5 s (torch loads), the final evaluation 5-20 s",
)


def add_learner_parser(sub: Any) -> None:
    p = add_command(sub, HELP)
    p.add_argument(
        "--run-dir", type=folder, required=True, help="folder for checkpoint, policy file and report (required)"
    )
    p.add_argument(
        "--resume",
        nargs="?",
        const="yes",
        choices=("yes", "auto"),
        help="continue from the checkpoint in --run-dir (an error if there is none); --resume auto: continue from it "
        "if there is one, else start afresh (what a restart policy or a requeued job runs; default: start afresh)",
    )
    add_process_args(
        p, LearnerConfig, "learner configuration (learner.config.LearnerConfig)", choices=registry_choices()
    )
    p.set_defaults(func=cmd_learner)


def cmd_learner(args: argparse.Namespace) -> int:
    # Everything is checked before anything starts: a resume from a folder without a checkpoint creates nothing
    # and opens no session.
    config: LearnerConfig = configure(LearnerConfig, args, "learner")
    if args.resume == "yes":
        check_checkpoint(args.run_dir)
    resume = args.resume == "yes" or (args.resume == "auto" and Checkpointer(args.run_dir).path.exists())
    check_folder(args.run_dir, "learner", "--run-dir")
    if not resume:
        # Only what a learner writes: a SLURM job's learner starts in a folder holding its job script.
        refuse_run(
            args.run_dir,
            "learner",
            f"--run-dir {args.run_dir}",
            "--resume",
            another="give another --run-dir",
            names=TRAINED,
        )
    check_device(config.phase1.device, "learner", "--phase1-device")
    conf = checked_zenoh(args, "learner", config.learner_id)
    stop = stop_on_signals()
    # The session first: a port in use is then an error before the run folder exists.
    with open_transport(conf, args, "learner") as transport:
        run_dir = make_folder(args.run_dir, "learner", "--run-dir")
        with open_monitor(sink_from_args(args), process=config.learner_id, recording_id=args.recording_id) as monitor:
            try:
                service = LearnerService(transport, config, run_dir, resume=resume, monitor=monitor)
            except CheckpointError as exc:
                fail("learner", str(exc))
            if config.threads > 0:
                import torch  # loaded by the service already, after its checkpoint was read: only a learner fits

                torch.set_num_threads(config.threads)
            with connect(service, transport):
                report = service.run(stop)
    line = (
        f"learner {config.learner_id}: {report.tuples_received} tuples from {len(report.actors)} actors, "
        f"policy version {report.policy_version}, final coverage {report.final_coverage_mean}; "
        f"report in {run_dir / 'report.json'}"
    )
    emit(report.to_dict(), args.json, line)
    return 0


def check_checkpoint(run_dir: Path) -> None:
    """``--resume`` needs a checkpoint in ``run_dir`` that is a readable archive (its content is read at start-up)."""
    path = Checkpointer(run_dir).path
    if not run_dir.is_dir():
        fail("learner", f"--resume: no folder {run_dir} (--run-dir names the folder of the run to resume)")
    if not path.is_file():
        fail("learner", f"--resume: no checkpoint in {run_dir} (a learner writes {path.name} every few seconds)")
    if not zipfile.is_zipfile(path):
        fail("learner", f"--resume: {path} is not a checkpoint (not an .npz archive)")
    problem = policy_problem(path)
    if problem:
        fail("learner", f"--resume: {path}: {problem}; a run cannot continue from it")
