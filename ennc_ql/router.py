"""``ennc-ql router``: a Zenoh router from the ``eclipse-zenoh`` package, for multi-machine runs.

PyPI has no ``zenohd``; a zenoh session opened in router mode routes for every client and peer that connects
to it, so learners and actors on other machines only need ``--mode client --connect tcp/<router>:7447``. The
official ``eclipse/zenoh`` image is the alternative where Docker runs (compose.yaml)::

    ennc-ql router                                        # listens on tcp/0.0.0.0:7447
    ennc-ql router --listen tcp/10.0.0.5:7447             # only on that address
    ennc-ql router --zenoh-config router.json5            # anything else zenoh's config file can set

Usage as a library (the stop event ends it; a signal handler or another thread sets it)::

    stop = threading.Event()
    run_router(zenoh_config(listen=["tcp/0.0.0.0:7447"], mode="router"), stop)
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
from typing import Any

import zenoh

from ennc_ql.command import fail, zenoh_conf, zenoh_message
from ennc_ql.parser import CommandHelp, add_command
from protocol import add_connection_args
from protocol.security import ROUTER
from tools.system import stop_on_signals

log = logging.getLogger(__name__)

DEFAULT_LISTEN = "tcp/0.0.0.0:7447"
"""7447 is zenoh's registered port; 0.0.0.0 rather than zenoh's own default ``[::]``, which fails where IPv6 is off."""


def _on_transport_event(event: zenoh.TransportEvent) -> None:
    # Runs on a zenoh thread: logging only, nothing that could block it.
    verb = "connected" if event.kind == zenoh.SampleKind.PUT else "disconnected"
    log.info("%s %s %s", event.transport.whatami, event.transport.zid, verb)


def run_router(conf: zenoh.Config, stop: threading.Event) -> None:
    """Route zenoh traffic with ``conf`` (its mode is forced to router) until ``stop`` is set."""
    conf.insert_json5("mode", json.dumps("router"))
    with zenoh.open(conf) as session:
        # history: clients already retrying connect during open(), before this listener exists.
        events = session.info.declare_transport_events_listener(_on_transport_event, history=True)
        try:
            log.info("zenoh router %s listening on %s", session.zid(), conf.get_json("listen/endpoints"))
            stop.wait()
        finally:
            events.undeclare()
    log.info("zenoh router closed")


def cmd_router(args: argparse.Namespace) -> int:
    """The ``router`` subcommand: run until SIGTERM or SIGINT."""
    if args.mode not in (None, "router"):
        fail("router", f"--mode {args.mode}: a router runs in router mode (leave --mode out)")
    # argparse's append action would add to a non-empty default instead of replacing it, hence the default here.
    if not args.listen and not args.zenoh_config:
        args.listen = [DEFAULT_LISTEN]
    conf = zenoh_conf(args, "router")
    user = json.loads(conf.get_json("transport/auth/usrpwd/user"))
    if user is not None and user != ROUTER:
        # Access control would then treat the router as that process, and that process's own file is no router's.
        fail(
            "router",
            f"--zenoh-config {args.zenoh_config}: authenticates as {user!r}, not as the router; give the router's own "
            f"file ({ROUTER}.json5 of ennc-ql secure init)",
        )
    try:
        run_router(conf, stop_on_signals())
    except zenoh.ZError as exc:
        fail("router", f"zenoh could not open the router: {zenoh_message(exc)}")
    return 0


HELP = CommandHelp(
    "router",
    "a Zenoh router, for runs over several machines",
    "A Zenoh router from the eclipse-zenoh package (PyPI has no zenohd): learners and actors on other machines "
    "join it with --mode client --connect tcp/HOST:7447 instead of reaching each other directly. Without --listen "
    f"or --zenoh-config it listens on {DEFAULT_LISTEN} (7447 is Zenoh's registered port). With the "
    "--zenoh-config that ennc-ql secure init writes it accepts only mutual-TLS sessions with a password, and lets "
    "each actor publish only under its own key. It runs until SIGTERM or Ctrl-C, then exits with status 0, as "
    "learner and actor do: a signal is how these processes are meant to stop.",
    (
        ("ennc-ql router", f"listen on {DEFAULT_LISTEN}"),
        ("ennc-ql router --zenoh-config secrets/router.json5", "the secure router of ennc-ql secure init"),
    ),
    "until stopped; ready in under a second",
)


def add_router_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register the ``router`` subcommand on ``subparsers`` (from ``ArgumentParser.add_subparsers``)."""
    p = add_command(subparsers, HELP)
    add_connection_args(p)
    p.set_defaults(func=cmd_router)
    return p
