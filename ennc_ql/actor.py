"""``ennc-ql actor``: one robot actor process, on a Zenoh session chosen by the shared flags.

The flags are generated from ``actors.config.ActorConfig`` (the field docstrings are the ``--help`` text),
``--config FILE`` reads the same fields from TOML, and flags given override the file. SIGTERM / SIGINT stop it
cleanly: it flushes its outbox for a few seconds; a second one cuts the flush short. Usage::

    ennc-ql actor --connect tcp/learner-host:7447 --actor-id actor-3 --learn 0-4 --seed 1
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from functools import partial
from typing import Any

from actors.actor import RobotActor
from actors.config import ActorConfig
from actors.wiring import connect
from ennc_ql.command import add_process_args, checked_zenoh, configure, emit, open_transport, registry_choices
from ennc_ql.parser import CommandHelp, add_command
from monitor import Monitor, Sink, open_monitor, sink_from_args
from monitor.relay import RelayMonitor
from protocol import Transport
from tools.system import stop_on_signals

HELP = CommandHelp(
    "actor",
    "one robot actor process, for runs over several machines",
    "One actor: --arenas independent arenas of the simulated world, each with all 10 robots. Until the first "
    "policy arrives every robot explores at random; then the robots it learns (--learn) act epsilon-greedily on "
    "their own Q tables (option 2) and the others follow the broadcast policy. It streams experience and Q-table "
    "changes to the learner, keeps everything unacknowledged in a bounded outbox (re-sent after a learner "
    "restart), and runs until --duration or SIGTERM/Ctrl-C, after which it flushes its outbox for a few seconds "
    "(--flush-timeout; a second Ctrl-C cuts it short, dropping what is still unacknowledged). "
    "ennc-ql up starts these for you; start them by hand for several machines. Every actor needs its own "
    "--actor-id (auto: one made of the host name and the process id).",
    (
        ("ennc-ql actor --connect tcp/LEARNER:7447 --actor-id actor-3", "join a learner that listens"),
        ("ennc-ql actor --mode client --connect tcp/ROUTER:7447 --actor-id auto --arenas 500", "through a router"),
    ),
    "until --duration or a signal; it sends its first experience within a few seconds",
)


def add_actor_parser(sub: Any) -> None:
    p = add_command(sub, HELP)
    add_process_args(p, ActorConfig, "actor configuration (actors.config.ActorConfig)", choices=registry_choices())
    p.set_defaults(func=cmd_actor)


def actor_monitor(sink: Sink, transport: Transport, config: ActorConfig, args: argparse.Namespace) -> Monitor:
    """``--rerun learner``: the actor's rows travel to the learner as ``ActorView`` messages (no Rerun here);
    any other sink: the actor logs them itself."""
    if sink.kind == "learner":
        return RelayMonitor(partial(transport.publish, transport.keys.view(config.actor_id)), config.actor_id)
    return open_monitor(sink, process=config.actor_id, recording_id=args.recording_id)


def cmd_actor(args: argparse.Namespace) -> int:
    config: ActorConfig = configure(ActorConfig, args, "actor")
    conf = checked_zenoh(args, "actor", config.actor_id)
    stop = stop_on_signals()
    sink = sink_from_args(args)
    with open_transport(conf, args, "actor") as transport, actor_monitor(sink, transport, config, args) as monitor:
        actor = RobotActor(transport, config, monitor=monitor)
        with connect(actor, transport):
            status = actor.run(stop, urgent=stop.urgent)
    line = (
        f"actor {config.actor_id}: {status.tuples_sent} tuples sent, {status.tuples_acked} acknowledged, policy "
        f"version {status.policy_version}"
    )
    emit(dataclasses.asdict(status), args.json, line)
    if status.tuples_sent and not status.tuples_acked and not status.policy_version:
        # Publishing never fails on a network: without a learner every message goes nowhere, unanswered.
        print(
            f"ennc-ql actor: warning: no learner answered: nothing was acknowledged and no policy came (--connect "
            f"{', '.join(args.connect) or 'none'}, --namespace {args.namespace or 'none'}); is a learner running "
            "there, with the same --namespace?",
            file=sys.stderr,
        )
    return 0
