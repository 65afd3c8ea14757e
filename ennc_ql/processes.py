"""``ennc-ql learner`` and ``ennc-ql actor``: one process each, on a Zenoh session chosen by the shared flags.

Each command's flags are generated from its configuration dataclass (``learner.config.LearnerConfig``,
``actors.config.ActorConfig``): the field docstrings are the ``--help`` text, ``--config FILE`` reads the same
fields from TOML, and flags given override the file. Both stop cleanly on SIGTERM / SIGINT: the learner checkpoints
and writes its report, the actor flushes its outbox for a few seconds. Usage::

    ennc-ql learner --listen tcp/0.0.0.0:7447 --run-dir runs/exp1 --duration 600
    ennc-ql actor --connect tcp/learner-host:7447 --actor-id actor-3 --learn 0-4 --seed 1
    ennc-ql learner --config runs/exp1/learner.toml --run-dir runs/exp1 --listen tcp/0.0.0.0:7447
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import tempfile
from pathlib import Path
from typing import Any, NoReturn

from actors.config import ActorConfig
from ennc_ql.config import ConfigError, add_config_flags, load_config
from ennc_ql.system import stop_on_signals
from learner.config import LearnerConfig
from monitor import add_rerun_args, open_monitor, sink_from_args
from protocol import add_connection_args, config_from_args, keys_from_args

log = logging.getLogger(__name__)


def fail(command: str, message: str) -> NoReturn:
    """A one-line error on stderr and exit status 2, as argparse does for a bad flag."""
    print(f"ennc-ql {command}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def configure(cls: type[Any], args: argparse.Namespace, command: str, defaults: dict[str, Any] | None = None) -> Any:
    """The command's configuration from its ``--config`` file and flags, or a one-line error naming what is wrong."""
    try:
        return load_config(cls, file=args.config, args=args, defaults=defaults)
    except ConfigError as exc:
        fail(command, str(exc))
    except OSError as exc:
        fail(command, f"--config {args.config}: {exc.strerror or exc}")


def writable_dir(path: Path, command: str, flag: str) -> Path:
    """``path`` created if needed and checked writable now, before any process state exists."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        fail(command, f"{flag} {path}: not a writable folder ({exc.strerror or exc})")
    return path


def _add_common(p: argparse.ArgumentParser, cls: type[Any], title: str, defaults: dict[str, Any] | None = None) -> None:
    p.add_argument("--config", metavar="FILE", help="TOML file with the configuration fields; flags given override it")
    p.add_argument("--json", action="store_true", help="print the final result as one JSON object")
    add_config_flags(p.add_argument_group(title), cls, defaults=defaults)
    add_connection_args(p)
    add_rerun_args(p)


def add_learner_parser(sub: Any) -> None:
    p = sub.add_parser("learner", help="the central ENNC-QL learner process")
    p.add_argument("--run-dir", type=Path, required=True, help="folder for checkpoint, policy file and report")
    p.add_argument("--resume", action="store_true", help="continue from the checkpoint in --run-dir")
    _add_common(p, LearnerConfig, "learner configuration (learner.config.LearnerConfig)")
    p.set_defaults(func=cmd_learner)


def cmd_learner(args: argparse.Namespace) -> int:
    from learner.checkpoint import CheckpointError
    from learner.service import LearnerService
    from learner.wiring import connect

    config: LearnerConfig = configure(LearnerConfig, args, "learner")
    run_dir = writable_dir(args.run_dir, "learner", "--run-dir")
    if config.threads > 0:
        import torch

        torch.set_num_threads(config.threads)
    stop = stop_on_signals()
    with (
        open_monitor(sink_from_args(args), process=config.learner_id, recording_id=args.recording_id) as monitor,
        _open_transport(args, "learner", config.learner_id) as transport,
    ):
        try:
            service = LearnerService(transport, config, run_dir, resume=args.resume, monitor=monitor)
        except CheckpointError as exc:
            fail("learner", str(exc))
        handles = connect(service, transport)
        try:
            report = service.run(stop)
        finally:
            for handle in reversed(handles):
                handle.close()
    if args.json:
        print(json.dumps(report.to_dict()))
    else:
        print(
            f"learner {config.learner_id}: {report.tuples_received} tuples from {len(report.actors)} actors, "
            f"policy version {report.policy_version}, final coverage {report.final_coverage_mean}; "
            f"report in {run_dir / 'report.json'}"
        )
    return 0


def add_actor_parser(sub: Any) -> None:
    p = sub.add_parser("actor", help="one robot actor process")
    _add_common(p, ActorConfig, "actor configuration (actors.config.ActorConfig)")
    p.set_defaults(func=cmd_actor)


def cmd_actor(args: argparse.Namespace) -> int:
    from actors.actor import RobotActor
    from actors.wiring import connect

    config: ActorConfig = configure(ActorConfig, args, "actor")
    stop = stop_on_signals()
    with (
        open_monitor(sink_from_args(args), process=config.actor_id, recording_id=args.recording_id) as monitor,
        _open_transport(args, "actor", config.actor_id) as transport,
    ):
        actor = RobotActor(transport, config, monitor=monitor)
        handles = connect(actor, transport)
        try:
            status = actor.run(stop)
        finally:
            for handle in reversed(handles):
                handle.close()
    if args.json:
        print(json.dumps(dataclasses.asdict(status)))
    else:
        print(f"actor {config.actor_id}: {status.tuples_sent} tuples sent, policy version {status.policy_version}")
    return 0


def _open_transport(args: argparse.Namespace, command: str, ident: str) -> Any:
    import zenoh

    from protocol import ZenohTransport

    try:
        conf = config_from_args(args)
    except (ValueError, OSError, zenoh.ZError) as exc:
        fail(command, f"zenoh configuration: {exc}")
    # With credentials, the router's access control lets this process publish only under its user name: any other
    # id would have every message dropped in silence, and its outbox would never drain.
    user = json.loads(conf.get_json("transport/auth/usrpwd/user"))
    if user is not None and user != ident:
        fail(command, f"the zenoh configuration authenticates as {user!r} but this process's id is {ident!r}")
    return ZenohTransport.open(conf, keys_from_args(args))
