"""The ``ennc-ql`` command line: thin subcommands over library functions.

Every subcommand that produces results accepts ``--json`` and then prints exactly one JSON object on stdout;
logs go to stderr.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ennc_ql.allocator import keep_freed_memory
from ennc_ql.config import positive
from monitor import add_rerun_args, open_monitor, sink_from_args

if TYPE_CHECKING:
    from sim import Controller, ScenarioConfig

log = logging.getLogger("ennc_ql")


def _emit(result: dict[str, Any], as_json: bool, table: str) -> None:
    if as_json:
        print(json.dumps(result))
    else:
        print(table)


def _controller(policy: str, scenario_name: str) -> tuple[Controller, ScenarioConfig, dict[str, Any]]:
    """A hand-made controller by name, or a learned policy from a policy file."""
    from sim import HAND_MADE, scenario

    if policy in HAND_MADE:
        return HAND_MADE[policy], scenario(scenario_name), {}
    path = Path(policy)
    if not path.exists():
        raise SystemExit(
            f"ennc-ql eval: {policy!r} is neither a hand-made policy ({', '.join(HAND_MADE)}) nor a policy file"
        )
    from algorithm.policy import PolicyController
    from algorithm.policy_file import PolicyFileError, load_policy, scenario_from_header

    try:
        learned, header = load_policy(path)
        cfg = scenario_from_header(header)
    except (PolicyFileError, TypeError, ValueError) as exc:
        raise SystemExit(f"ennc-ql eval: {exc}") from None
    info = {"method": learned.method, "prototypes_per_action": header["prototypes_per_action"]}
    return PolicyController(learned), cfg, info


def cmd_eval(args: argparse.Namespace) -> int:
    from monitor.trial import trial_hook
    from sim import evaluate

    controller, cfg, info = _controller(args.policy, args.scenario)
    if args.record_trial >= args.trials:
        raise SystemExit(f"ennc-ql eval: --record-trial {args.record_trial} but only {args.trials} trials run")
    start = time.perf_counter()
    with open_monitor(sink_from_args(args), process="eval", recording_id=args.recording_id) as monitor:
        hook = None
        if monitor.enabled:
            monitor.send_blueprint(eval_trial=True)
            hook = trial_hook(monitor, cfg, arena=args.record_trial)
        result = evaluate(cfg, controller, trials=args.trials, steps=args.steps, seed=args.seed, on_step=hook)
    out = {
        "policy": args.policy,
        **info,
        "scenario": cfg.name,
        "trials": args.trials,
        "steps": args.steps,
        "seed": args.seed,
        "coverage_mean": round(result.coverage_mean, 4),
        "coverage_std": round(result.coverage_std, 4),
        "coverage_per_trial": [round(float(c), 4) for c in result.coverage_per_trial],
        "seconds": round(time.perf_counter() - start, 3),
    }
    rows = "\n".join(f"  trial {i:>3}  {c:6.2f} %" for i, c in enumerate(out["coverage_per_trial"]))
    table = (
        f"policy {out['policy']} on {cfg.name}: {args.trials} trials x {args.steps} steps, seed {args.seed}\n"
        f"{rows}\n  mean       {out['coverage_mean']:6.2f} %  (std {out['coverage_std']:.2f})"
    )
    _emit(out, args.json, table)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from ennc_ql.bench import actor_table, bench_actor, bench_ennc, bench_sim, ennc_table

    if args.what == "ennc":
        out = bench_ennc(
            args.patterns, args.cycles, args.phase1_tuples, region_size=args.region_patterns, threads=args.threads
        )
        _emit(out, args.json, ennc_table(out))
    if args.what == "transport":
        from ennc_ql.bench_transport import bench_transport, transport_table

        out = bench_transport(args.actors, args.batch_size, args.seconds, args.shared_memory, args.secure)
        _emit(out, args.json, transport_table(out))
    if args.what == "sim":
        with open_monitor(sink_from_args(args), process="bench", recording_id=args.recording_id) as monitor:
            out = bench_sim(args.scenario, seconds=args.seconds, monitor=monitor)
        rates = out["robot_steps_per_s"]
        table = "\n".join(
            f"{name:>9}: {rates[name] / 1e6:6.2f} M robot-steps/s at {out['arenas_by_controller'][name]} arenas "
            f"(target {out['target'][name] / 1e6:.0f} M: {'met' if out['meets_target'][name] else 'NOT met'})"
            for name in rates
        )
        _emit(out, args.json, table)
    if args.what == "phase1":
        from ennc_ql.bench import bench_phase1, phase1_table

        out = bench_phase1(tuple(args.store_sizes))
        _emit(out, args.json, phase1_table(out))
    if args.what == "broadcast":
        from ennc_ql.bench_broadcast import bench_broadcast, broadcast_table

        out = bench_broadcast(args.prototypes, rounds=args.rounds, scenario_name=args.scenario)
        _emit(out, args.json, broadcast_table(out))
    if args.what == "actor":
        policy = None
        if args.policy is not None:
            from algorithm.policy_file import load_policy

            policy = load_policy(args.policy)[0]
        out = bench_actor(args.scenario, args.arenas, args.seconds, policy=policy)
        _emit(out, args.json, actor_table(out))
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from algorithm.experiments import Budget
    from ennc_ql.reproduce import markdown_table, reproduce

    budget = Budget.quick() if args.quick else Budget()
    processes = args.processes or (1 if args.quick else 5)
    out_dir = Path(args.out) if args.out else Path("runs") / ("reproduce-quick" if args.quick else "reproduce")
    report = reproduce(budget, processes, out_dir, methods=args.methods or None, jobs=args.jobs)
    report["output"] = str(out_dir)
    _emit(
        report, args.json, markdown_table(report) + f"\nwritten to {out_dir}/ (results.md, results.json, figure5.png)"
    )
    return 0


def cmd_ablate(args: argparse.Namespace) -> int:
    from algorithm.experiments import Budget
    from ennc_ql.ablate import Setup, ablate, markdown_table, parse_sets
    from ennc_ql.config import ConfigError
    from ennc_ql.processes import fail

    out_dir = Path(args.out) if args.out else Path("runs") / f"ablate-{args.method}"
    try:
        sweep = parse_sets(args.set)
        base = Setup(budget=Budget.quick() if args.quick else Budget())
        report = ablate(args.method, sweep, base, args.processes, out_dir, jobs=args.jobs)
    except ConfigError as exc:
        fail("ablate", str(exc))
    report["output"] = str(out_dir)
    _emit(
        report, args.json, markdown_table(report) + f"\nwritten to {out_dir}/ (results.md, results.json, ablation.png)"
    )
    return 0


def method_names() -> list[str]:
    """Every method ``reproduce`` knows, in the order of its table."""
    from algorithm.experiments import METHODS
    from ennc_ql.reproduce import HAND_MADE_ORDER

    return [*HAND_MADE_ORDER, *METHODS]


def build_parser(router_only: bool = False) -> argparse.ArgumentParser:
    """Every command's parser; ``router_only``: the router's alone, whose process never loads the simulator (the
    other commands' configurations import it, and with it numba's compiler: 40 MB of resident memory)."""
    from ennc_ql.router import add_router_parser

    parser = argparse.ArgumentParser(prog="ennc-ql", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr")
    sub = parser.add_subparsers(dest="command", required=True)
    if router_only:
        add_router_parser(sub)
        return parser
    from sim import SCENARIOS

    p = sub.add_parser("eval", help="evaluate a policy on seeded test trials (metric A)")
    p.add_argument(
        "--policy",
        default="a-cmommt",
        help="a hand-made controller (a-cmommt; any other name lists them) or a policy file (.npz)",
    )
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument("--trials", type=positive(int), default=10, help="independent test trials (default 10)")
    p.add_argument("--steps", type=positive(int), default=1000, help="steps per trial (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the test trials (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--record-trial", type=int, default=0, metavar="K", help="with --rerun: the trial to draw (default 0)"
    )
    add_rerun_args(p)
    p.set_defaults(func=cmd_eval)

    from ennc_ql.chaos import add_chaos_parser
    from ennc_ql.processes import add_actor_parser, add_learner_parser
    from ennc_ql.secure import add_secure_parser
    from ennc_ql.up import add_up_parser

    add_up_parser(sub)
    add_learner_parser(sub)
    add_actor_parser(sub)
    add_router_parser(sub)
    add_secure_parser(sub)
    add_chaos_parser(sub)

    p = sub.add_parser("reproduce", help="the paper's Figure 5 and 6: every method, tables and a bar chart")
    p.add_argument("--quick", action="store_true", help="reduced budget: 1 process per method, shorter learning")
    p.add_argument("--processes", type=positive(int), help="learning processes per method (default 5, quick 1)")
    names = method_names()
    p.add_argument("--methods", nargs="+", choices=names, metavar="METHOD", help=f"run only these: {', '.join(names)}")
    p.add_argument("--out", help="output folder (default runs/reproduce[-quick])")
    p.add_argument("--jobs", type=positive(int), default=1, help="learning processes run at once (default 1)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_reproduce)

    from algorithm.experiments import METHODS

    p = sub.add_parser(
        "ablate", help="one method under parameter overrides (a sweep), K learning processes per variant, same tests"
    )
    p.add_argument("method", choices=list(METHODS), help="the learned method")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=V1[,V2...]",
        help="override a field of the setup by dotted path (budget.phase2.alpha, budget.phase1.max_classes, "
        "scenario.action_steps, lost_behaviour, ...); several values sweep it, several --set sweep their product",
    )
    p.add_argument("--processes", type=positive(int), default=3, help="learning processes per variant (default 3)")
    p.add_argument("--jobs", type=positive(int), default=1, help="learning processes run at once (default 1)")
    p.add_argument("--quick", action="store_true", help="reproduce's reduced budget as the base")
    p.add_argument("--out", help="output folder (default runs/ablate-METHOD)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_ablate)

    p = sub.add_parser("bench", help="measure performance figures")
    p.add_argument(
        "what",
        choices=["sim", "ennc", "transport", "actor", "broadcast", "phase1"],
        help="sim: simulator robot-steps/s; ennc: ENNC vs k-means and phase 1 time; transport: actors -> store; "
        "actor: a phase-2 actor slice against the bare simulator; broadcast: policy message size and cost against "
        "prototypes per action; phase1: the learner's phase 1 against store size",
    )
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument(
        "--seconds", type=float, default=1.5, help="sim: measuring time per configuration; actor: per phase of a round"
    )
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
    p.add_argument(
        "--store-sizes",
        type=positive(int),
        nargs="+",
        default=[100_000, 300_000, 1_000_000],
        metavar="N",
        help="phase1: store sizes in tuples (default 100000 300000 1000000)",
    )
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
    p.add_argument("--json", action="store_true", help="print one JSON object")
    from ennc_ql.bench_transport import add_bench_transport_args

    add_bench_transport_args(p)  # --actors, --batch-size, --shared-memory; --seconds is per phase
    add_rerun_args(p)  # sim: arena 0 drawn every few steps, to measure what monitoring costs
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    # The command is the first word that is not a flag: the only options before it (-v, -h) take no value.
    command = next((w for w in words if not w.startswith("-")), None)
    args = build_parser(router_only=command == "router").parse_args(words)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    keep_freed_memory()  # every process of ours churns ~1 MB message buffers
    code: int = args.func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
