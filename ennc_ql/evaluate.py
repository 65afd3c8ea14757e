"""``ennc-ql eval``: a hand-made controller or a learned policy file on seeded test trials (metric A)::

ennc-ql eval --policy a-cmommt --trials 10 --steps 1000 --seed 0
ennc-ql eval --policy runs/<id>/policy.npz --rerun save trial.rrd --record-trial 3
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.policy import TALLY, PolicyController
from algorithm.policy_file import PolicyFileError, load_policy, scenario_from_header
from algorithm.selection import TEST_SEED
from ennc_ql.command import emit, fail
from ennc_ql.parser import CommandHelp, add_command, suggestion
from monitor import add_rerun_args, open_monitor, sink_from_args
from monitor.trial import trial_hook
from sim import CONTROLLERS, HAND_MADE, ORACLES, SCENARIOS, Controller, ScenarioConfig, evaluate, scenario
from sim.rollout import WITHIN_NOISE, EvalResult, within_noise
from sim.world import MAX_ARENAS
from tools.config import non_negative, positive, too_long

MAX_STEPS = 100_000
"""The longest trial eval runs: a trial's steps run one after another, so a mistyped count would run silently for
days where a bound answers at once."""

HELP = CommandHelp(
    "eval",
    "score a policy on seeded test trials: a hand-made controller or a learned policy file",
    "Scores a policy with metric A, the percentage of the targets that at least one robot observes, averaged over "
    "every step of every test trial (10 robots, 10 targets, 1000-step trials, as in the paper). The policy is a "
    "hand-made controller by name (random, local, a-cmommt: A-CMOMMT tuned on training trials, on what robots sense "
    "or are told; a-cmommt-public: its public untuned parameters; force-6d, force-6d-shared: its law on the learned "
    "state's information; force-recall: that law with the robot's own memory of a lost target), the labelled "
    "oracle a-cmommt-oracle (true target positions no robot senses), or a policy file written by a run "
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
        help=f"a hand-made controller ({', '.join(HAND_MADE)}), the oracle ({', '.join(ORACLES)}) or a policy "
        "file (.npz)",
    )
    p.add_argument("--scenario", default="cmommt-v1", choices=sorted(SCENARIOS), help="the simulated world")
    p.add_argument(
        "--trials",
        type=positive(int, most=MAX_ARENAS, why=" (all trials run side by side, about 12 KB each)"),
        default=10,
        help=f"independent test trials (at most {MAX_ARENAS})",
    )
    p.add_argument(
        "--steps",
        type=positive(int, most=MAX_STEPS, why=" (a hundred times the paper's 1000)"),
        default=1000,
        help=f"steps per trial (at most {MAX_STEPS})",
    )
    p.add_argument(
        "--seed",
        type=non_negative(int),
        default=TEST_SEED,
        help=f"seed of the test trials (0 or more; default {TEST_SEED}, the trials up's final figure reads)",
    )
    p.add_argument(
        "--against",
        metavar="POLICY",
        help="a second policy (a name or a policy file) scored on the same trials: both, and their paired "
        "difference per trial with its standard error (default: none)",
    )
    p.add_argument(
        "--law-margin",
        type=non_negative(float),
        metavar="M",
        help="read the --policy file (a law action set's) with this law margin instead of its own: a robot departs "
        "from the move law only where another move's value beats it by more than M; 0: the plain argmax "
        "(default: the file's)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--record-trial", type=non_negative(int), default=0, metavar="K", help="with --rerun: the trial to draw"
    )
    add_rerun_args(p)
    p.set_defaults(func=cmd_eval)


def cmd_eval(args: argparse.Namespace) -> int:
    if args.record_trial >= args.trials:
        fail("eval", f"--record-trial {args.record_trial}: only trials 0 to {args.trials - 1} run (--trials)")
    controller, cfg, info = _controller(args.policy, args.scenario, law_margin=args.law_margin)
    other = None if args.against is None else _controller(args.against, args.scenario, "--against")
    start = time.perf_counter()
    with open_monitor(sink_from_args(args), process="eval", recording_id=args.recording_id) as monitor:
        hook = None
        if monitor.enabled:
            monitor.send_blueprint(eval_trial=True)
            hook = trial_hook(monitor, cfg, arena=args.record_trial)
        result = evaluate(cfg, controller, trials=args.trials, steps=args.steps, seed=args.seed, on_step=hook)
    off_law = controller.off_law() if isinstance(controller, PolicyController) else None
    out = {
        "policy": args.policy,
        **info,
        "scenario": cfg.name,
        "trials": args.trials,
        "steps": args.steps,
        "seed": args.seed,
        **_scores(result),
    }
    if off_law is not None:
        out["off_law_pct"] = round(off_law.pct, 4)
        out["shared_decisions_pct"] = round(off_law.shared_pct, 4)
        out["shared_off_law_pct"] = round(off_law.shared_off_pct, 4)
    rows = "\n".join(f"  trial {i:>3}  {c:6.2f} %" for i, c in enumerate(out["coverage_per_trial"]))
    table = (
        f"policy {_title(args.policy, info)} on {cfg.name}: {args.trials} trials x {args.steps} steps, seed {args.seed}"
        f"\n{rows}\n  mean       {out['coverage_mean']:6.2f} %  (std {out['coverage_std']:.2f})\n"
        f"  {_spread_line(out)}"
    )
    if "off_law_pct" in out:
        table += (
            f"\n  {out['off_law_pct']:.1f} % of the robots' decisions took another move than law; where a teammate "
            f"shared the robot's targets ({out['shared_decisions_pct']:.1f} % of the decisions), "
            f"{out['shared_off_law_pct']:.1f} % of them did"
        )
    if other is not None:
        # The second policy runs on the scenario of the first: a paired comparison needs the same trials.
        against = evaluate(cfg, other[0], trials=args.trials, steps=args.steps, seed=args.seed)
        mean, se = result.minus(against)
        out["against"] = {"policy": args.against, **other[2], **_scores(against)}
        out["paired_difference"] = {"mean": round(mean, 4), "se": round(se, 4), "trials": args.trials}
        table += (
            f"\nagainst {_title(args.against, other[2])} on the same trials: "
            f"{out['against']['coverage_mean']:.2f} %  (std {out['against']['coverage_std']:.2f})\n"
            f"  {_spread_line(out['against'])}\n"
            f"paired difference (policy - against): {mean:+.2f} ± {se:.2f} points (s.e., {args.trials} trials)"
            f"{WITHIN_NOISE if within_noise(mean, se) else ''}"
        )
    out["seconds"] = round(time.perf_counter() - start, 3)
    emit(out, args.json, table)
    return 0


def _scores(result: EvalResult) -> dict[str, Any]:
    """Coverage and the team's spread over the targets, rounded for printing."""
    spread = {} if result.cooperation is None else result.cooperation.summary()
    return {
        "coverage_mean": round(result.coverage_mean, 4),
        "coverage_std": round(result.coverage_std, 4),
        "coverage_per_trial": [round(float(c), 4) for c in result.coverage_per_trial],
        **{k: round(v, 4) for k, v in spread.items()},
    }


def _spread_line(scores: dict[str, Any]) -> str:
    return (
        f"per robot-step: {scores['only_shared_pct']:.1f} % only teammate-watched targets in view, "
        f"{scores['none_in_view_pct']:.1f} % no target in view; "
        f"{scores['robots_per_covered_target']:.3f} robots per covered target"
    )


def _title(policy: str, info: dict[str, Any]) -> str:
    """The policy's name, with a learned policy's formulation (and its law margin, where it has one)."""
    if "formulation" not in info:
        return policy
    margin = f", law margin {info['law_margin']:g}" if "law_margin" in info else ""
    return f"{policy} ({info['formulation']}{margin})"


def _controller(
    policy: str, scenario_name: str, flag: str = "--policy", law_margin: float | None = None
) -> tuple[Controller, ScenarioConfig, dict[str, Any]]:
    """A hand-made controller by name, or a learned policy from a policy file (read with ``law_margin`` when
    given); a one-line error otherwise."""
    if policy in CONTROLLERS:
        if law_margin is not None:
            fail("eval", f"--law-margin: {policy} is a hand-made controller, not a learned policy file")
        return CONTROLLERS[policy], scenario(scenario_name), {}
    if not policy.strip():
        fail("eval", f"{flag}: expected a hand-made controller or a policy file, got an empty value")
    problem = too_long(policy)
    if problem:
        fail("eval", f"{flag}: {problem}")
    path = Path(policy)
    if path.is_dir():
        inside = path / "policy.npz"
        hint = f"; its policy is {inside}" if inside.is_file() else ""
        fail("eval", f"{flag} {policy}: a folder, not a policy file{hint}")
    if not path.exists():
        if path.suffix or len(path.parts) > 1:  # a path, not a name
            fail("eval", f"{flag} {policy}: no such policy file")
        close = suggestion(policy, list(CONTROLLERS))
        fail("eval", f"{flag}: unknown policy {policy!r}{close} (one of {', '.join(CONTROLLERS)}, or a policy file)")
    try:
        learned, header = load_policy(path)
        cfg = scenario_from_header(header)
    except (PolicyFileError, TypeError, ValueError) as exc:
        fail("eval", f"{flag} {policy}: {str(exc).removeprefix(f'{path}: ')}")
    if law_margin is not None:
        try:
            learned = dataclasses.replace(learned, law_margin=law_margin)
        except ValueError as exc:
            fail("eval", f"--law-margin {law_margin:g}: {exc}")
    info = {
        "method": learned.method,
        "formulation": "{0} state, {2} moves, {1} reward".format(*learned.formulation.names),
        "prototypes_per_action": header["prototypes_per_action"],
    }
    if learned.formulation.actions.law is None:
        return PolicyController(learned), cfg, info
    info["law_margin"] = learned.law_margin
    # Counted for the --policy only: how far the learned policy departs from the law it holds as a move.
    tally = np.zeros(TALLY, np.int64) if flag == "--policy" else None
    return PolicyController(learned, tally=tally), cfg, info
