"""The ``ennc-ql chaos`` command: its parser, and a run from the options to the figures printed and the exit
status."""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any

from ennc_ql.command import configure, fail, registry_choices, writable_dir
from ennc_ql.parser import CommandHelp, add_command, say
from protocol import check_id
from tools.chaos.checks import results_table
from tools.chaos.network import NetworkError, unavailable
from tools.chaos.observe import WaitTimeout
from tools.chaos.options import (
    DEFAULT_DURATION_S,
    DEFAULT_FAULT_INTERVAL_S,
    DEFAULT_RSS_INTERVAL_S,
    FAULTS,
    NETWORK_FAULTS,
    SOAK_RSS_INTERVAL_S,
    ChaosOptions,
    parse_duration,
    parse_faults,
)
from tools.chaos.run import Chaos
from tools.cluster import SET_BY_UP, UP_PRESETS, UpConfig
from tools.config import add_config_flags, file_path, folder, positive

LEARNER_EXTRA_S = 3600.0
"""The learner's own duration is chaos's plus this: chaos ends it by SIGTERM once the actors drained, never the
clock, so every acknowledged message is in its report."""


def _interrupted(signum: int, _frame: FrameType | None) -> None:
    # SIGTERM as Ctrl-C: the run's `finally` then kills every child instead of leaving them behind.
    raise KeyboardInterrupt(signal.Signals(signum).name)


def chaos_options(args: argparse.Namespace) -> ChaosOptions:
    """The options of ``ennc-ql chaos``, or a one-line error (exit 2) naming the bad value."""
    if args.soak is not None and args.chaos_duration is not None:
        fail("chaos", "give --duration or --soak, not both")
    try:
        duration = parse_duration(args.soak) if args.soak is not None else args.chaos_duration or DEFAULT_DURATION_S
    except ValueError as exc:
        fail("chaos", f"--soak: {exc}")
    try:
        faults = parse_faults(args.faults, args.secure)
    except ValueError as exc:
        fail("chaos", f"--faults: {exc}")
    rss_interval = args.rss_interval or (SOAK_RSS_INTERVAL_S if args.soak is not None else DEFAULT_RSS_INTERVAL_S)
    return ChaosOptions(duration, args.secure, args.fault_interval, faults, rss_interval)


def cmd_chaos(args: argparse.Namespace) -> int:
    options = chaos_options(args)
    options, skipped = without_unavailable_network(options)
    config: UpConfig = configure(UpConfig, args, "chaos", defaults=UP_PRESETS)
    config = dataclasses.replace(config, duration=options.duration + LEARNER_EXTRA_S)
    run_id = args.run_id if args.run_id is not None else time.strftime("chaos-%Y%m%d-%H%M%S")
    try:
        check_id(run_id, "--run-id")
        namespace = check_id(f"chaos-{run_id}", "--run-id (in the namespace chaos-<id>)")
    except ValueError as exc:
        fail("chaos", str(exc))
    if (args.runs / run_id).exists() and any((args.runs / run_id).iterdir()):
        # A report or checkpoint left there by another run would be taken for this one's.
        fail("chaos", f"--run-id {run_id}: {args.runs / run_id} is not empty; choose another run id")
    run_dir = writable_dir(args.runs / run_id, "chaos", "--runs")
    # Only now that every argument is checked: a notice never comes before an error.
    if skipped:
        print(f"ennc-ql chaos: skipping {', '.join(skipped)}: {next(iter(skipped.values()))}", file=sys.stderr)
    signal.signal(signal.SIGTERM, _interrupted)
    try:
        out = Chaos(options, config, run_dir, run_id, namespace, skipped).run()
    except KeyboardInterrupt:
        print("ennc-ql chaos: interrupted; every child process was killed", file=sys.stderr)
        return 130
    except (WaitTimeout, NetworkError) as exc:
        print(f"ennc-ql chaos: the cluster did not start: {exc}; see the logs in {run_dir}", file=sys.stderr)
        return 1
    (run_dir / "chaos.json").write_text(json.dumps(out, indent=2))
    say(json.dumps(out) if args.json else results_table(out))
    return 0 if out["passed"] else 1


def without_unavailable_network(options: ChaosOptions) -> tuple[ChaosOptions, dict[str, str]]:
    """The options without the network faults if namespaces cannot be made here, and each one skipped with why (the
    caller says so once every argument is checked); a one-line error if nothing else was asked for."""
    wanted = [f for f in options.faults if f in NETWORK_FAULTS]
    reason = unavailable() if wanted else None
    if reason is None:
        return options, {}
    rest = tuple(f for f in options.faults if f not in NETWORK_FAULTS)
    if not rest:
        fail("chaos", f"--faults: network namespaces are needed for {', '.join(wanted)}: {reason}")
    return dataclasses.replace(options, faults=rest), dict.fromkeys(wanted, reason)


HELP = CommandHelp(
    "chaos",
    "the fault suite: a real cluster trains under injected faults, then the reliability contract is checked",
    "Starts a router, the learner and the actors as real processes (secure by default: mutual TLS, a password "
    "per process and access control; --no-secure for plain TCP) and, once the first policy is checkpointed, "
    "injects one fault every --fault-interval seconds in rotation: the learner killed just after a checkpoint "
    "and resumed, the router restarted, an actor stopped past the Zenoh lease, an actor killed and restarted, a "
    "poisoned batch, batches spoofing another actor, a peer without a password, a peer with another CA's "
    "certificate, a 160 MiB message, and (in network namespaces it creates, as root) a partition, delay and loss "
    "on an actor's link. It then checks the reliability contract from the figures of different "
    "processes (exactly-once storage, every acknowledged visit in the final tables or counted as dropped, versions "
    "strictly increasing across restarts, the poisoned stream flowing on, nothing stored from hostile peers, bounded "
    "memory), prints them and exits 1 if a check fails. RUN/chaos.json holds what --json prints.",
    (
        ("ennc-ql chaos", "120 s, secure, every fault, one every 20 s"),
        ("ennc-ql chaos --no-secure --duration 90", "plain TCP (the two TLS faults do not apply)"),
        ("ennc-ql chaos --soak 30m", "a long run at full load, memory sampled every minute"),
    ),
    "--duration (120 s, at least one round of faults) plus start-up and the drain",
)


def add_chaos_parser(sub: Any) -> None:
    p = add_command(sub, HELP)
    p.add_argument(
        "--duration",
        dest="chaos_duration",
        type=positive(float),
        metavar="SECONDS",
        help=f"run length from the cluster's start (default: {DEFAULT_DURATION_S:.0f}; one round of faults at least)",
    )
    p.add_argument(
        "--soak",
        metavar="DURATION",
        help=f"a long run, e.g. 90s, 30m, 2h (sets the duration; RSS every {SOAK_RSS_INTERVAL_S:.0f} s; default: none)",
    )
    p.add_argument(
        "--secure",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="TLS, passwords and access control, with the TLS faults (default: on)",
    )
    p.add_argument(
        "--fault-interval",
        type=positive(float),
        default=DEFAULT_FAULT_INTERVAL_S,
        metavar="SECONDS",
        help=f"seconds between fault starts (default: {DEFAULT_FAULT_INTERVAL_S:.0f})",
    )
    p.add_argument("--faults", metavar="NAME,...", help=f"faults in rotation (default: all of {', '.join(FAULTS)})")
    p.add_argument(
        "--rss-interval",
        type=positive(float),
        metavar="SECONDS",
        help="seconds between RSS samples "
        f"(default: {DEFAULT_RSS_INTERVAL_S:.0f}, {SOAK_RSS_INTERVAL_S:.0f} with --soak)",
    )
    p.add_argument("--runs", type=folder, default=Path("runs"), metavar="DIR", help="parent folder of the run folder")
    p.add_argument("--run-id", metavar="ID", help="run folder name (default: chaos-<start time>)")
    p.add_argument(
        "--config",
        type=file_path,
        metavar="FILE",
        help="TOML file of the cluster's configuration, e.g. a run's up.toml (default: none)",
    )
    p.add_argument("--json", action="store_true", help="print the figures and checks as one JSON object")
    add_config_flags(
        p.add_argument_group("cluster configuration (tools.cluster.UpConfig)"),
        UpConfig,
        exclude=(*SET_BY_UP, "duration"),
        defaults=UP_PRESETS,
        choices=registry_choices(),
    )
    p.set_defaults(func=cmd_chaos)
