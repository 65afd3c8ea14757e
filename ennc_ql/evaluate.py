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
from ennc_ql.command import emit, fail
from ennc_ql.config import non_negative, positive
from ennc_ql.parser import CommandHelp, add_command
from monitor import add_rerun_args, open_monitor, sink_from_args
from monitor.trial import trial_hook
from sim import HAND_MADE, SCENARIOS, Controller, ScenarioConfig, evaluate, scenario

HELP = CommandHelp(
    "eval",
    "score a policy on seeded test trials: a hand-made controller or a learned policy file",
    "Scores a policy with metric A, the percentage of the targets that at least one robot observes, averaged over "
    "every step of every test trial (10 robots, 10 targets, 1000-step trials, as in the paper). The policy is a "
    "hand-made controller by name (random, local, a-cmommt: A-CMOMMT on what robots sense or are told, "
    "a-cmommt-oracle: the same law on true positions, force-6d, force-6d-shared) or a policy file written by a run "
    "(runs/<id>/policy.npz). The same seed gives the same trials, so two policies scored with it compare directly. "
    "With --rerun, one trial is drawn in the Rerun viewer.",
    (
        ("ennc-ql eval --policy a-cmommt", "the hand-made reference on 10 trials"),
        ("ennc-ql eval --policy runs/<id>/policy.npz --trials 50", "a learned policy, as up's final figure"),
        ("ennc-ql eval --policy runs/<id>/policy.npz --rerun spawn --trials 1", "watch one trial in the viewer"),
    ),
    "2-2.5 s for 10 trials, a hand-made controller or a learned policy, about 4 s for 50; the first run after an "
    "install takes 3 s more, while numba compiles the simulator",
)


def add_eval_parser(sub: Any) -> None:
    p = add_command(sub, HELP)
    p.add_argument(
        "--policy",
        default="a-cmommt",
        help=f"a hand-made controller ({', '.join(HAND_MADE)}) or a policy file (.npz)",
    )
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS), help="the simulated world")
    p.add_argument("--trials", type=positive(int), default=10, help="independent test trials")
    p.add_argument("--steps", type=positive(int), default=1000, help="steps per trial")
    p.add_argument("--seed", type=non_negative(int), default=0, help="seed of the test trials (0 or more)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--record-trial", type=non_negative(int), default=0, metavar="K", help="with --rerun: the trial to draw"
    )
    add_rerun_args(p)
    p.set_defaults(func=cmd_eval)


def cmd_eval(args: argparse.Namespace) -> int:
    if args.record_trial >= args.trials:
        fail("eval", f"--record-trial {args.record_trial}: only trials 0 to {args.trials - 1} run (--trials)")
    controller, cfg, info = _controller(args.policy, args.scenario)
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
    """A hand-made controller by name, or a learned policy from a policy file; a one-line error otherwise."""
    if policy in HAND_MADE:
        return HAND_MADE[policy], scenario(scenario_name), {}
    path = Path(policy)
    if path.is_dir():
        inside = path / "policy.npz"
        hint = f"; its policy is {inside}" if inside.is_file() else ""
        fail("eval", f"--policy {policy}: a folder, not a policy file{hint}")
    if not path.exists():
        names = ", ".join(HAND_MADE)
        fail("eval", f"--policy {policy}: neither a hand-made controller ({names}) nor an existing policy file")
    try:
        learned, header = load_policy(path)
        cfg = scenario_from_header(header)
    except (PolicyFileError, TypeError, ValueError) as exc:
        fail("eval", f"--policy {policy}: {str(exc).removeprefix(f'{path}: ')}")
    info = {"method": learned.method, "prototypes_per_action": header["prototypes_per_action"]}
    return PolicyController(learned), cfg, info
