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
from typing import Any

from sim import HAND_MADE, SCENARIOS, evaluate, scenario

log = logging.getLogger("ennc_ql")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _emit(result: dict[str, Any], as_json: bool, table: str) -> None:
    if as_json:
        print(json.dumps(result))
    else:
        print(table)


def cmd_eval(args: argparse.Namespace) -> int:
    cfg = scenario(args.scenario)
    if args.policy not in HAND_MADE:
        raise SystemExit(f"ennc-ql eval: unknown policy {args.policy!r}; choose one of {', '.join(HAND_MADE)}")
    start = time.perf_counter()
    result = evaluate(cfg, HAND_MADE[args.policy], trials=args.trials, steps=args.steps, seed=args.seed)
    out = {
        "policy": args.policy,
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
    from ennc_ql.bench import bench_sim

    if args.what == "sim":
        out = bench_sim(args.scenario, seconds=args.seconds)
        rates = out["robot_steps_per_s"]
        table = "\n".join(
            f"{name:>9}: {rates[name] / 1e6:6.2f} M robot-steps/s at {out['arenas_by_controller'][name]} arenas "
            f"(target {out['target'][name] / 1e6:.0f} M: {'met' if out['meets_target'][name] else 'NOT met'})"
            for name in rates
        )
        _emit(out, args.json, table)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ennc-ql", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("eval", help="evaluate a policy on seeded test trials (metric A)")
    p.add_argument("--policy", default="a-cmommt", help=f"one of {', '.join(HAND_MADE)}")
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument("--trials", type=_positive_int, default=10, help="independent test trials (default 10)")
    p.add_argument("--steps", type=_positive_int, default=1000, help="steps per trial (default 1000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the test trials (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("bench", help="measure performance figures")
    p.add_argument("what", choices=["sim"], help="sim: simulator robot-steps per second")
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS))
    p.add_argument("--seconds", type=float, default=1.5, help="measuring time per configuration")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    code: int = args.func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
