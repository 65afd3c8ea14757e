"""``ennc-ql learner`` and ``ennc-ql actor``: one process each, on a Zenoh session chosen by the shared flags.

Both stop cleanly on SIGTERM / SIGINT: the learner checkpoints and writes its report, the actor flushes its
outbox for a few seconds. Usage::

    ennc-ql learner --listen tcp/0.0.0.0:7447 --run-dir runs/exp1 --duration 600
    ennc-ql actor --connect tcp/learner-host:7447 --id actor-3 --learn 0-4 --seed 1
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import signal
import socket
import threading
from pathlib import Path
from typing import Any

from actors.actor import ActorConfig, RobotActor, parse_robots
from algorithm.agent import Phase2Config
from algorithm.phase1 import Phase1Config
from learner.service import LearnerConfig, LearnerService
from monitor import add_rerun_args, open_monitor, sink_from_args
from protocol import ZenohTransport, add_connection_args, check_id, config_from_args, keys_from_args
from sim import FEATURIZERS, SCENARIOS

log = logging.getLogger(__name__)


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT (the process then winds down instead of dying mid-write)."""
    stop = threading.Event()

    def handler(signum: int, _frame: object) -> None:
        log.info("received %s, stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    return stop


def _positive(kind: type) -> Any:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}") from None
        if value <= 0:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}")
        return value

    return parse


def _identifier(text: str) -> str:
    try:
        return check_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _actor_id(text: str) -> str:
    # Replicas started from one command line (compose deploy.replicas) need distinct ids: a container's
    # hostname is unique per replica, a pid per process on one host.
    if text == "auto":
        host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname())[:40]
        text = f"actor-{host}-{os.getpid()}"
    return _identifier(text)


def _robots(text: str) -> tuple[int, ...]:
    try:
        return parse_robots(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_learner_parser(sub: Any) -> None:
    p = sub.add_parser("learner", help="the central ENNC-QL learner process")
    p.add_argument("--run-dir", required=True, help="folder for checkpoint, policy file and report")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint in --run-dir")
    p.add_argument("--id", type=_identifier, default="learner", help="learner id (default: learner)")
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument("--featurizer", default="collab6d", choices=sorted(FEATURIZERS))
    p.add_argument("--duration", type=_positive(float), help="stop after this many seconds (default: until SIGTERM)")
    p.add_argument("--min-tuples", type=_positive(int), default=150_000, help="tuples before the first phase 1")
    p.add_argument("--store-capacity", type=_positive(int), default=1_000_000, help="tuples kept in the store")
    p.add_argument("--refit-growth", type=float, default=0.0, help="refit when data grew this many times (0: never)")
    p.add_argument("--phase1-cycles", type=_positive(int), default=250, help="ENNC cycles per fit")
    p.add_argument("--phase1-patterns", type=_positive(int), default=30_000, help="tuples per action per fit")
    p.add_argument("--broadcast-interval", type=_positive(float), default=3.0, help="seconds between broadcasts")
    p.add_argument("--eval-interval", type=_positive(float), default=20.0, help="seconds between evaluations")
    p.add_argument("--eval-trials", type=_positive(int), default=10, help="test trials per evaluation")
    p.add_argument(
        "--final-eval-trials", type=_positive(int), default=50, help="test trials of the final policy's figure"
    )
    p.add_argument("--checkpoint-interval", type=_positive(float), default=5.0, help="seconds between checkpoints")
    p.add_argument("--status-interval", type=_positive(float), default=2.0, help="seconds between status messages")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=0, help="torch threads for phase 1 (default 0: torch's choice)")
    p.add_argument("--json", action="store_true", help="print the final report as one JSON object")
    add_connection_args(p)
    add_rerun_args(p)
    p.set_defaults(func=cmd_learner)


def cmd_learner(args: argparse.Namespace) -> int:
    config = LearnerConfig(
        learner_id=args.id,
        scenario=args.scenario,
        featurizer=args.featurizer,
        store_capacity=args.store_capacity,
        min_tuples=args.min_tuples,
        refit_growth=args.refit_growth,
        phase1=Phase1Config(max_iterations=1, n_cycles=args.phase1_cycles, max_patterns=args.phase1_patterns),
        broadcast_interval=args.broadcast_interval,
        eval_interval=args.eval_interval,
        eval_trials=args.eval_trials,
        final_eval_trials=args.final_eval_trials,
        checkpoint_interval=args.checkpoint_interval,
        status_interval=args.status_interval,
        duration=args.duration,
        seed=args.seed,
    )
    if args.threads > 0:
        import torch

        torch.set_num_threads(args.threads)
    stop = stop_on_signals()
    run_dir = Path(args.run_dir)
    with (
        open_monitor(sink_from_args(args), process=args.id, recording_id=args.recording_id) as monitor,
        ZenohTransport.open(config_from_args(args), keys_from_args(args)) as transport,
    ):
        try:
            service = LearnerService(transport, config, run_dir, resume=args.resume, monitor=monitor)
        except FileNotFoundError as exc:
            raise SystemExit(f"ennc-ql learner: {exc}") from None
        service.start()
        try:
            report = service.run(stop)
        finally:
            service.close()
    if args.json:
        print(json.dumps(report))
    else:
        print(
            f"learner {args.id}: {report['tuples_received']} tuples from {len(report['actors'])} actors, "
            f"policy version {report['policy_version']}, final coverage {report['final_coverage_mean']}; "
            f"report in {run_dir / 'report.json'}"
        )
    return 0


def add_actor_parser(sub: Any) -> None:
    p = sub.add_parser("actor", help="one robot actor process")
    p.add_argument(
        "--id", type=_actor_id, required=True, help="actor id, unique in the run ('auto': from hostname and pid)"
    )
    p.add_argument("--learn", type=_robots, help="robots whose tables this actor learns, e.g. 0-4 (default: all)")
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument("--featurizer", default="collab6d", choices=sorted(FEATURIZERS))
    p.add_argument("--arenas", type=_positive(int), default=256, help="arenas simulated side by side")
    p.add_argument("--seed", type=int, default=0, help="run seed (combined with the actor id)")
    p.add_argument("--duration", type=_positive(float), help="stop after this many seconds (default: until SIGTERM)")
    p.add_argument("--batch-size", type=_positive(int), default=16384, help="tuples per experience message")
    p.add_argument("--outbox", type=_positive(int), default=256, help="unacknowledged messages kept")
    p.add_argument("--epsilon", type=float, default=0.1, help="exploration rate of phase 2")
    p.add_argument(
        "--flush-timeout", type=float, default=10.0, help="seconds to wait for acks of the outbox when stopping"
    )
    p.add_argument("--status-interval", type=_positive(float), default=2.0)
    p.add_argument("--json", action="store_true", help="print the final counters as one JSON object")
    add_connection_args(p)
    add_rerun_args(p)
    p.set_defaults(func=cmd_actor)


def cmd_actor(args: argparse.Namespace) -> int:
    config = ActorConfig(
        actor_id=args.id,
        scenario=args.scenario,
        featurizer=args.featurizer,
        learn=args.learn,
        arenas=args.arenas,
        seed=args.seed,
        batch_size=args.batch_size,
        outbox_limit=args.outbox,
        duration=args.duration,
        status_interval=args.status_interval,
        phase2=Phase2Config(epsilon=args.epsilon),
        flush_timeout=args.flush_timeout,
    )
    stop = stop_on_signals()
    with (
        open_monitor(sink_from_args(args), process=args.id, recording_id=args.recording_id) as monitor,
        ZenohTransport.open(config_from_args(args), keys_from_args(args)) as transport,
    ):
        try:
            actor = RobotActor(transport, config, monitor=monitor)
        except ValueError as exc:
            raise SystemExit(f"ennc-ql actor: {exc}") from None
        actor.start()
        try:
            counters = actor.run(stop)
        finally:
            actor.close()
    if args.json:
        print(json.dumps(counters))
    else:
        print(
            f"actor {args.id}: {int(counters['tuples_sent'])} tuples sent, policy version {counters['policy_version']}"
        )
    return 0
