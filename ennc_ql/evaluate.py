"""``ennc-ql eval``: a hand-made controller or a learned policy file on seeded test trials (metric A)::

ennc-ql eval --policy a-cmommt --trials 10 --steps 1000 --seed 0
ennc-ql eval --policy runs/<id>/policy.npz --rerun save trial.rrd --record-trial 3
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from algorithm.policy import PolicyController
from algorithm.policy_file import PolicyFileError, load_policy, scenario_from_header
from ennc_ql.command import emit
from ennc_ql.config import positive
from monitor import add_rerun_args, open_monitor, sink_from_args
from monitor.trial import trial_hook
from sim import HAND_MADE, SCENARIOS, Controller, ScenarioConfig, evaluate, scenario


def add_eval_parser(sub: Any) -> None:
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


def cmd_eval(args: argparse.Namespace) -> int:
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
    emit(out, args.json, table)
    return 0


def _controller(policy: str, scenario_name: str) -> tuple[Controller, ScenarioConfig, dict[str, Any]]:
    """A hand-made controller by name, or a learned policy from a policy file."""
    if policy in HAND_MADE:
        return HAND_MADE[policy], scenario(scenario_name), {}
    path = Path(policy)
    if not path.exists():
        raise SystemExit(
            f"ennc-ql eval: {policy!r} is neither a hand-made policy ({', '.join(HAND_MADE)}) nor a policy file"
        )
    try:
        learned, header = load_policy(path)
        cfg = scenario_from_header(header)
    except (PolicyFileError, TypeError, ValueError) as exc:
        raise SystemExit(f"ennc-ql eval: {exc}") from None
    info = {"method": learned.method, "prototypes_per_action": header["prototypes_per_action"]}
    return PolicyController(learned), cfg, info
