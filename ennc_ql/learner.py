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
from pathlib import Path
from typing import Any

from ennc_ql.command import add_process_args, configure, emit, fail, open_transport, writable_dir
from ennc_ql.system import stop_on_signals
from learner.checkpoint import Checkpointer, CheckpointError
from learner.config import LearnerConfig
from learner.service import LearnerService
from learner.wiring import connect
from monitor import open_monitor, sink_from_args


def add_learner_parser(sub: Any) -> None:
    p = sub.add_parser("learner", help="the central ENNC-QL learner process")
    p.add_argument("--run-dir", type=Path, required=True, help="folder for checkpoint, policy file and report")
    p.add_argument(
        "--resume",
        nargs="?",
        const="yes",
        choices=("yes", "auto"),
        help="continue from the checkpoint in --run-dir (an error if there is none); --resume auto: continue from it "
        "if there is one, else start afresh (what a restart policy or a requeued job runs)",
    )
    add_process_args(p, LearnerConfig, "learner configuration (learner.config.LearnerConfig)")
    p.set_defaults(func=cmd_learner)


def cmd_learner(args: argparse.Namespace) -> int:
    config: LearnerConfig = configure(LearnerConfig, args, "learner")
    run_dir = writable_dir(args.run_dir, "learner", "--run-dir")
    resume = args.resume == "yes" or (args.resume == "auto" and Checkpointer(run_dir).path.exists())
    stop = stop_on_signals()
    with (
        open_monitor(sink_from_args(args), process=config.learner_id, recording_id=args.recording_id) as monitor,
        open_transport(args, "learner", config.learner_id) as transport,
    ):
        try:
            service = LearnerService(transport, config, run_dir, resume=resume, monitor=monitor)
        except CheckpointError as exc:
            fail("learner", str(exc))
        if config.threads > 0:
            import torch  # loaded by the service already: only a learner that fits needs it

            torch.set_num_threads(config.threads)
        handles = connect(service, transport)
        try:
            report = service.run(stop)
        finally:
            for handle in reversed(handles):
                handle.close()
    line = (
        f"learner {config.learner_id}: {report.tuples_received} tuples from {len(report.actors)} actors, "
        f"policy version {report.policy_version}, final coverage {report.final_coverage_mean}; "
        f"report in {run_dir / 'report.json'}"
    )
    emit(report.to_dict(), args.json, line)
    return 0
