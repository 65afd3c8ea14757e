"""``ennc-ql bench WHAT``: one benchmark, its figures printed as a table or as one JSON object (``--json``)::

ennc-ql bench sim --json
ennc-ql bench transport --actors 4 --secure
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from algorithm.policy_file import load_policy
from ennc_ql.bench.transport import add_bench_transport_args
from ennc_ql.command import emit
from ennc_ql.config import positive
from monitor import add_rerun_args, open_monitor, sink_from_args
from sim import SCENARIOS

Figures = tuple[dict[str, Any], str]
"""A benchmark's figures and the table that shows them."""

# Each runner imports its benchmark when it runs: some load torch and scikit-learn, which the others never need.


def _sim(args: argparse.Namespace) -> Figures:
    from ennc_ql.bench.sim import bench_sim, sim_table

    with open_monitor(sink_from_args(args), process="bench", recording_id=args.recording_id) as monitor:
        out = bench_sim(args.scenario, seconds=args.seconds, monitor=monitor)
    return out, sim_table(out)


def _ennc(args: argparse.Namespace) -> Figures:
    from ennc_ql.bench.ennc import bench_ennc, ennc_table

    out = bench_ennc(
        args.patterns, args.cycles, args.phase1_tuples, region_size=args.region_patterns, threads=args.threads
    )
    return out, ennc_table(out)


def _transport(args: argparse.Namespace) -> Figures:
    from ennc_ql.bench.transport import bench_transport, transport_table

    out = bench_transport(args.actors, args.batch_size, args.seconds, args.shared_memory, args.secure)
    return out, transport_table(out)


def _actor(args: argparse.Namespace) -> Figures:
    from ennc_ql.bench.actor import actor_table, bench_actor

    policy = None if args.policy is None else load_policy(args.policy)[0]
    out = bench_actor(args.scenario, args.arenas, args.seconds, policy=policy)
    return out, actor_table(out)


def _broadcast(args: argparse.Namespace) -> Figures:
    from ennc_ql.bench.broadcast import bench_broadcast, broadcast_table

    out = bench_broadcast(args.prototypes, rounds=args.rounds, scenario_name=args.scenario)
    return out, broadcast_table(out)


def _phase1(args: argparse.Namespace) -> Figures:
    from ennc_ql.bench.phase1 import bench_phase1, phase1_table

    out = bench_phase1(tuple(args.store_sizes))
    return out, phase1_table(out)


BENCHMARKS: dict[str, Callable[[argparse.Namespace], Figures]] = {
    "sim": _sim,
    "ennc": _ennc,
    "transport": _transport,
    "actor": _actor,
    "broadcast": _broadcast,
    "phase1": _phase1,
}


def cmd_bench(args: argparse.Namespace) -> int:
    out, table = BENCHMARKS[args.what](args)
    emit(out, args.json, table)
    return 0


def add_bench_parser(sub: Any) -> None:
    p = sub.add_parser("bench", help="measure performance figures")
    p.add_argument(
        "what",
        choices=list(BENCHMARKS),
        help="sim: simulator robot-steps/s; ennc: ENNC vs k-means and phase 1 time; transport: actors -> store; "
        "actor: a phase-2 actor slice against the bare simulator; broadcast: policy message size and cost against "
        "prototypes per action; phase1: the learner's phase 1 against store size",
    )
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument(
        "--seconds", type=float, default=1.5, help="sim: measuring time per configuration; actor: per phase of a round"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _add_learning_core_args(p)
    _add_runtime_args(p)
    add_bench_transport_args(p)  # --actors, --batch-size, --shared-memory; --seconds is per phase
    add_rerun_args(p)  # sim: arena 0 drawn every few steps, to measure what monitoring costs
    p.set_defaults(func=cmd_bench)


def _add_learning_core_args(p: argparse.ArgumentParser) -> None:
    """The flags of ``ennc`` and ``phase1``."""
    p.add_argument("--patterns", type=positive(int), default=100_000, help="ennc: patterns of the ENNC fit")
    p.add_argument("--cycles", type=positive(int), default=250, help="ennc: ENNC cycles / k-means iterations")
    p.add_argument(
        "--region-patterns",
        type=int,
        default=20_000,
        help="ennc: patterns of the region-shaped 6-D set that grows thousands of prototypes (0 skips it)",
    )
    p.add_argument(
        "--threads",
        type=positive(int),
        default=None,
        help="ennc: threads of ENNC and k-means alike (default: all; 1 is steadier on busy shared cores)",
    )
    p.add_argument(
        "--phase1-tuples", type=int, default=1_000_000, help="ennc: tuples of the timed phase 1 (0 skips it)"
    )
    p.add_argument(
        "--store-sizes",
        type=positive(int),
        nargs="+",
        default=[100_000, 300_000, 1_000_000],
        metavar="N",
        help="phase1: store sizes in tuples (default 100000 300000 1000000)",
    )


def _add_runtime_args(p: argparse.ArgumentParser) -> None:
    """The flags of ``actor`` and ``broadcast``."""
    p.add_argument("--arenas", type=positive(int), default=500, help="actor: arenas of the slice (default 500, as up)")
    p.add_argument("--policy", help="actor: a policy file to act on (default: learn one by phase 1 on exploration)")
    p.add_argument(
        "--prototypes",
        type=positive(int),
        nargs="+",
        default=[100, 300, 1000, 3000, 10000],
        metavar="P",
        help="broadcast: prototypes per action of each measured policy (default 100 300 1000 3000 10000)",
    )
    p.add_argument("--rounds", type=positive(int), default=5, help="broadcast: rounds per size (default 5)")
