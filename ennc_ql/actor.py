"""``ennc-ql actor``: one robot actor process, on a Zenoh session chosen by the shared flags.

The flags are generated from ``actors.config.ActorConfig`` (the field docstrings are the ``--help`` text),
``--config FILE`` reads the same fields from TOML, and flags given override the file. SIGTERM / SIGINT stop it
cleanly: it flushes its outbox for a few seconds. Usage::

    ennc-ql actor --connect tcp/learner-host:7447 --actor-id actor-3 --learn 0-4 --seed 1
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

from actors.actor import RobotActor
from actors.config import ActorConfig
from actors.wiring import connect
from ennc_ql.command import add_process_args, configure, emit, open_transport
from ennc_ql.system import stop_on_signals
from monitor import open_monitor, sink_from_args


def add_actor_parser(sub: Any) -> None:
    p = sub.add_parser("actor", help="one robot actor process")
    add_process_args(p, ActorConfig, "actor configuration (actors.config.ActorConfig)")
    p.set_defaults(func=cmd_actor)


def cmd_actor(args: argparse.Namespace) -> int:
    config: ActorConfig = configure(ActorConfig, args, "actor")
    stop = stop_on_signals()
    with (
        open_monitor(sink_from_args(args), process=config.actor_id, recording_id=args.recording_id) as monitor,
        open_transport(args, "actor", config.actor_id) as transport,
    ):
        actor = RobotActor(transport, config, monitor=monitor)
        handles = connect(actor, transport)
        try:
            status = actor.run(stop)
        finally:
            for handle in reversed(handles):
                handle.close()
    line = f"actor {config.actor_id}: {status.tuples_sent} tuples sent, policy version {status.policy_version}"
    emit(dataclasses.asdict(status), args.json, line)
    return 0
