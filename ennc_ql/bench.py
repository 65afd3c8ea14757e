"""``ennc-ql bench NAME``: one benchmark, its figures printed as a table or as one JSON object (``--json``)::

ennc-ql bench sim --json
ennc-ql bench transport --actors 4 --secure
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from algorithm.policy_file import PolicyFileError, load_policy
from ennc_ql.command import emit, fail
from ennc_ql.parser import CommandHelp, add_command, add_commands
from monitor import add_rerun_args, open_monitor, sink_from_args
from sim import FORMULATIONS, SCENARIOS
from sim.world import MAX_ARENAS
from tools.config import file_path, non_negative, positive

Figures = tuple[dict[str, Any], str]
"""A benchmark's figures and the table that shows them."""

# Each runner imports its benchmark when it runs: some load torch and scikit-learn, which the others never need.


def _sim(args: argparse.Namespace) -> Figures:
    from tools.bench.sim import bench_sim, sim_table

    with open_monitor(sink_from_args(args), process="bench", recording_id=args.recording_id) as monitor:
        out = bench_sim(args.scenario, seconds=args.seconds, monitor=monitor)
    return out, sim_table(out)


def _ennc(args: argparse.Namespace) -> Figures:
    from tools.bench.ennc import bench_ennc, ennc_table

    out = bench_ennc(
        args.patterns, args.cycles, args.phase1_tuples, region_size=args.region_patterns, threads=args.threads
    )
    return out, ennc_table(out)


def _transport(args: argparse.Namespace) -> Figures:
    from tools.bench.transport import bench_transport, transport_table

    out = bench_transport(args.actors, args.batch_size, args.seconds, args.shared_memory, args.secure)
    return out, transport_table(out)


def _actor(args: argparse.Namespace) -> Figures:
    from tools.bench.actor import actor_table, bench_actor

    policy = None
    if args.policy is not None:
        try:
            policy = load_policy(args.policy)[0]
        except PolicyFileError as exc:
            fail("bench actor", f"--policy {args.policy}: {str(exc).removeprefix(f'{args.policy}: ')}")
    formulation = None if args.formulation is None else FORMULATIONS[args.formulation]
    try:
        out = bench_actor(args.scenario, args.arenas, args.seconds, policy=policy, formulation=formulation)
    except ValueError as exc:
        fail("bench actor", f"--formulation {args.formulation}: {exc}")
    return out, actor_table(out)


def _broadcast(args: argparse.Namespace) -> Figures:
    from tools.bench.broadcast import bench_broadcast, broadcast_table

    out = bench_broadcast(args.prototypes, rounds=args.rounds, scenario_name=args.scenario)
    return out, broadcast_table(out)


def _phase1(args: argparse.Namespace) -> Figures:
    from tools.bench.phase1 import bench_phase1, phase1_table

    out = bench_phase1(tuple(args.store_sizes))
    return out, phase1_table(out)


BENCHMARKS: dict[str, tuple[Callable[[argparse.Namespace], Figures], CommandHelp]] = {
    "sim": (
        _sim,
        CommandHelp(
            "sim",
            "simulator robot-steps per second",
            "Robot-steps per second of the simulator (one robot advanced one step, with the 6-D featurization and the "
            "collaborative reward computed) under the random controller and A-CMOMMT, at the best of several batch "
            "sizes (arenas simulated side by side). With --rerun it draws arena 0 every few steps, to measure what "
            "monitoring costs.",
            (
                ("ennc-ql bench sim", "the table"),
                ("ennc-ql bench sim --json --seconds 3", "longer, as one JSON object"),
            ),
            "about 15 s (measured on 2 busy cores)",
        ),
    ),
    "ennc": (
        _ennc,
        CommandHelp(
            "ennc",
            "ENNC against k-means, and ENNC-QL phase 1 on a million tuples",
            "Fits ENNC (--cycles) on --patterns standardized 6-D states of one action from random exploration, and "
            "in the same run scikit-learn's KMeans with as many centres; then a region-shaped set that grows "
            "thousands of prototypes (--region-patterns), and ENNC-QL phase 1 on --phase1-tuples tuples.",
            (
                ("ennc-ql bench ennc", "every part"),
                ("ennc-ql bench ennc --phase1-tuples 0 --region-patterns 0 --threads 1", "ENNC against k-means only"),
            ),
            "about 1.5 min on an idle machine (the sum of its parts in docs/performance.md)",
        ),
    ),
    "transport": (
        _transport,
        CommandHelp(
            "transport",
            "experience from publisher processes into the learner's store, against raw Zenoh",
            "Starts --actors publisher processes that stream experience batches with blocking congestion control "
            "into the learner's real receive path (decode, validate, de-duplicate, store), and in the same run the "
            "raw Zenoh baseline with the same payloads; reports tuples per second, their ratio, the receiver's CPU "
            "per batch and what was lost.",
            (
                ("ennc-ql bench transport", "2 publishers, TCP on loopback"),
                ("ennc-ql bench transport --actors 4 --secure", "4 publishers over mutual TLS"),
            ),
            "about 6 s (measured on 2 busy cores)",
        ),
    ),
    "actor": (
        _actor,
        CommandHelp(
            "actor",
            "one actor slice in phase 2 against the bare simulator",
            "Robot-steps per second of one actor slice (--arenas arenas) in phase 2 with a learned policy, beside "
            "the bare simulator in the same run; without --policy it first learns one by phase 1 on exploration.",
            (
                ("ennc-ql bench actor", "with a policy learned for the occasion"),
                ("ennc-ql bench actor --policy runs/<id>/policy.npz --json", "with a run's policy"),
            ),
            "3.5 min learning its policy, 12 s with --policy (measured on 2 busy cores)",
        ),
    ),
    "broadcast": (
        _broadcast,
        CommandHelp(
            "broadcast",
            "the policy message's size and cost against prototypes per action",
            "For each size in --prototypes: the PolicyUpdate message's size, the time to build, encode, decode and "
            "apply it in an actor, and its delivery to another process over TCP on loopback (median of --rounds).",
            (
                ("ennc-ql bench broadcast", "100 to 10 000 prototypes per action"),
                ("ennc-ql bench broadcast --prototypes 300 3000 --rounds 3 --json", "two sizes"),
            ),
            "about 8 s (measured on 2 busy cores)",
        ),
    ),
    "phase1": (
        _phase1,
        CommandHelp(
            "phase1",
            "the learner's phase 1 against store size",
            "ENNC-QL phase 1 as the learner runs it (one iteration, ENNC fitted on at most 30 000 tuples per "
            "action, Q targets computed on all) on stores of --store-sizes tuples of random exploration.",
            (
                ("ennc-ql bench phase1", "100 000, 300 000 and 1 000 000 tuples"),
                ("ennc-ql bench phase1 --store-sizes 50000 --json", "one size"),
            ),
            "8 min measured on 2 cores shared with other jobs; less on an idle machine",
        ),
    ),
}


def cmd_bench(args: argparse.Namespace) -> int:
    out, table = BENCHMARKS[args.what][0](args)
    emit(out, args.json, table)
    return 0


BENCH = CommandHelp(
    "bench",
    "benchmarks: simulator, ENNC, transport, actor, policy broadcast, phase 1",
    "Measures one part of the system and prints its figures as a table, or as one JSON object with --json. Each "
    "benchmark is a subcommand with its own flags (ennc-ql bench NAME --help). Benchmarks are commands, never timed "
    "tests: the figures depend on what else the machine is doing.",
    (("ennc-ql bench sim", "simulator speed"), ("ennc-ql bench transport --json", "the learner's receive path")),
    "6 s to 8 min, by benchmark (each one's page says)",
)


def add_bench_parser(sub: Any) -> None:
    benches = add_commands(add_command(sub, BENCH), dest="what", title="benchmarks")
    parsers = {name: add_command(benches, info) for name, (_, info) in BENCHMARKS.items()}
    for p in parsers.values():
        p.add_argument("--json", action="store_true", help="print one JSON object")
        p.set_defaults(func=cmd_bench)
    for name in ("sim", "actor", "broadcast"):
        parsers[name].add_argument(
            "--scenario", default="cmommt-v1", choices=sorted(SCENARIOS), help="the simulated world"
        )
    parsers["sim"].add_argument("--seconds", type=positive(float), default=1.5, help="measuring time per batch size")
    add_rerun_args(parsers["sim"])  # arena 0 drawn every few steps, to measure what monitoring costs
    _add_ennc_args(parsers["ennc"])
    parsers["transport"].add_argument(
        "--seconds", type=positive(float), default=1.5, help="measuring time of each phase"
    )
    add_bench_transport_args(parsers["transport"])
    parsers["actor"].add_argument(
        "--seconds", type=positive(float), default=1.5, help="measuring time of each phase of a round"
    )
    parsers["actor"].add_argument(
        "--arenas",
        type=positive(int, most=MAX_ARENAS, why=" (arenas run side by side, about 12 KB each)"),
        default=500,
        help="arenas of the slice, as up's",
    )
    parsers["actor"].add_argument(
        "--policy", type=file_path, help="a policy file to act on (default: learn one by phase 1 on exploration)"
    )
    parsers["actor"].add_argument(
        "--formulation",
        choices=sorted(FORMULATIONS),
        help="the formulation the actor runs the policy in, for its trial rules (default: the run's default "
        "formulation when the policy's state, reward and moves are its own, else the paper's trial rules)",
    )
    parsers["broadcast"].add_argument(
        "--prototypes",
        type=positive(int),
        nargs="+",
        default=[100, 300, 1000, 3000, 10000],
        metavar="P",
        help="prototypes per action of each measured policy",
    )
    parsers["broadcast"].add_argument("--rounds", type=positive(int), default=5, help="rounds per size")
    parsers["phase1"].add_argument(
        "--store-sizes",
        type=positive(int),
        nargs="+",
        default=[100_000, 300_000, 1_000_000],
        metavar="N",
        help="store sizes in tuples",
    )


def _add_ennc_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--patterns", type=positive(int), default=100_000, help="patterns of the ENNC fit")
    p.add_argument("--cycles", type=positive(int), default=250, help="ENNC cycles, and k-means iterations at most")
    p.add_argument(
        "--region-patterns",
        type=non_negative(int),
        default=20_000,
        help="patterns of the region-shaped 6-D set that grows thousands of prototypes (0 skips it)",
    )
    p.add_argument(
        "--threads",
        type=positive(int),
        default=None,
        help="threads of ENNC and k-means alike (default: all; 1 is steadier on busy shared cores)",
    )
    p.add_argument(
        "--phase1-tuples", type=non_negative(int), default=1_000_000, help="tuples of the timed phase 1 (0 skips it)"
    )


def add_bench_transport_args(parser: argparse.ArgumentParser) -> None:
    """The ``bench transport`` flags, besides its measuring time per phase (``--seconds``)."""
    parser.add_argument("--actors", type=positive(int), default=2, help="publisher processes")
    parser.add_argument("--batch-size", type=positive(int), default=16384, help="tuples per batch")
    parser.add_argument(
        "--shared-memory",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="let zenoh use shared memory, as between processes of one host (default: off, as across hosts)",
    )
    parser.add_argument(
        "--secure", action="store_true", help="mutual TLS and password authentication on every link, as a secure run"
    )
