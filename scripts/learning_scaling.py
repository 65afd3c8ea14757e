"""The learning-scaling figure: what learning added over the base law against training time, on the test trials.

One ``ennc-ql up --duration D --seed S`` per seed, D the longest time asked for; while it trains, the learner's
checkpoint is copied as its clock passes each time asked for (the tables it holds then, every increment merged or
pending, are a run of that length's last tables). Each copy is saved as the learner saves its last tables
(``algorithm.selection.SaveRule``: a law action set's margin chosen on 300 validation trials) and scored on the test
trials (``TEST_SEED``) paired against the formulation's base law, with its decisions off the law overall and where a
teammate shares the robot's targets. Runs and copies already in ``--out`` are reused, so the grid can be grown::

    python scripts/learning_scaling.py --minutes 1 2 4 8 16 --seeds 0 1
    python scripts/learning_scaling.py --plot-only      # score and draw from what --out holds

Writes ``--out``/scaling.json (one row per run and time) and ``--figure`` (default docs/learning_scaling.png).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from algorithm.policy import Policy, evaluate_off_law
from algorithm.selection import TEST_SEED, SaveRule
from learner.checkpoint import CHECKPOINT
from learner.config import LearnerConfig
from learner.policy_state import PolicyState
from sim import CONTROLLERS, evaluate, scenario
from sim.formulation import DEFAULT_FORMULATION
from tools.config import load_config

ENNC_QL = Path(sys.executable).with_name("ennc-ql")


def snapshot_name(seconds: float) -> str:
    return f"t{seconds:g}.npz"


def train(run: Path, formulation: str, seconds: list[float], seed: int) -> None:
    """The run (or the one kept from before), its checkpoint copied as the learner's clock passes each of
    ``seconds`` (the last a little before its end, which a final checkpoint may not pass)."""
    snaps = run.with_name(run.name + "-snaps")
    if all((snaps / snapshot_name(s)).exists() for s in seconds):
        return
    shutil.rmtree(run, ignore_errors=True)
    snaps.mkdir(parents=True, exist_ok=True)
    command = [str(ENNC_QL), "up", f"--duration={max(seconds):g}", f"--formulation={formulation}", f"--seed={seed}"]
    command += [f"--runs={run.parent}", f"--run-id={run.name}", "--rerun=off", "--json"]
    print(" ".join(command), flush=True)
    done = threading.Event()
    copier = threading.Thread(target=copy_checkpoints, args=(run, snaps, [s - 0.5 for s in seconds], done))
    copier.start()
    try:
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    finally:
        done.set()
        copier.join()


def copy_checkpoints(run: Path, snaps: Path, seconds: list[float], done: threading.Event) -> None:
    """Copy the checkpoint each time its clock has passed the next of ``seconds``: its meta read alone (a checkpoint
    is tens of MB), from the same open file that is then copied, since the learner replaces it by a rename."""
    pending = sorted(seconds)
    while pending and not done.wait(0.5):
        try:
            with open(run / CHECKPOINT, "rb") as file:
                with np.load(file, allow_pickle=False) as data:
                    if "tables" not in data.files:
                        continue
                    meta = json.loads(data["meta"].tobytes().decode())
                passed = [s for s in pending if meta["elapsed"] >= s]
                for s in passed:
                    file.seek(0)
                    with open(snaps / snapshot_name(round(s + 0.5)), "wb") as out:
                        shutil.copyfileobj(file, out)
        except (OSError, ValueError, KeyError):
            continue  # none yet, or cut off mid-write of a copy: the next one
        for s in passed:
            pending.remove(s)
            print(f"  {snapshot_name(round(s + 0.5))}: {meta['elapsed']:.1f} s, policy v{meta['version']}", flush=True)


def held_policy(run: Path, snapshot: Path) -> tuple[Policy, float]:
    """The policy the learner held at the snapshot, as it would save it, and its clock."""
    config = load_config(LearnerConfig, file=run / "learner.toml")
    cfg = scenario(config.scenario)
    state = PolicyState(cfg.n_robots, config.resolved, cfg.name, cfg.action_steps, config.method, config.team_policy)
    with np.load(snapshot, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    meta = json.loads(arrays.pop("meta").tobytes().decode())
    state.restore(arrays, meta)
    policy = state.policy()
    assert policy is not None, f"{snapshot}: no tables yet"
    return policy, float(meta["elapsed"])


def score(run: Path, snapshot: Path, trials: int) -> dict[str, Any]:
    policy, elapsed = held_policy(run, snapshot)
    cfg = scenario("cmommt-v1")
    read, saved = SaveRule(cfg, None, 300, 1000).decide(policy, elapsed)
    result, off = evaluate_off_law(cfg, read, trials, 1000, TEST_SEED)
    law_name = policy.formulation.base_law
    law = evaluate(cfg, CONTROLLERS[law_name], trials, 1000, seed=TEST_SEED)
    gain, se = result.minus(law)
    visits = int(policy.visits.sum()) if policy.visits is not None else 0
    return {
        "seconds": round(elapsed, 1),
        "coverage": round(result.coverage_mean, 3),
        "base_law": law_name,
        "minus_base_law": round(gain, 3),
        "minus_base_law_se": round(se, 3),
        "margin": saved.margin,
        "off_law_pct": None if off is None else round(off.pct, 2),
        "shared_off_law_pct": None if off is None else round(off.shared_off_pct, 2),
        "visits": visits,
        "trials": trials,
    }


def plot(rows: list[dict[str, Any]], figure: Path) -> None:
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    minutes = sorted({r["minutes"] for r in rows})
    for seed in sorted({r["seed"] for r in rows}):
        mine = sorted((r for r in rows if r["seed"] == seed), key=lambda r: r["minutes"])
        x = [r["minutes"] for r in mine]
        y = np.array([r["minus_base_law"] for r in mine])
        e = 2 * np.array([r["minus_base_law_se"] for r in mine])
        ax.errorbar(x, y, yerr=e, marker="o", capsize=3, label=f"seed {seed}")
        for r in mine:
            ax.annotate(
                f"{r['off_law_pct']:.0f}%",
                (r["minutes"], r["minus_base_law"]),
                fontsize=7,
                textcoords="offset points",
                xytext=(5, 5),
            )
    ax.axhline(0.0, color="grey", linestyle="--", label=f"the base law ({rows[0]['base_law']})")
    ax.set_xscale("log", base=2)
    ax.set_xticks(minutes, [f"{m:g}" for m in minutes])
    ax.set_xlabel("training time, minutes (ennc-ql up, 2 actors, 2 cores)")
    ax.set_ylabel("learned − base law, points of metric A (± 2 s.e.)")
    ax.set_title(
        f"ENNC-QL on {rows[0]['formulation']}: what learning added, by training time\n"
        f"(saved as a run of that length saves it; {rows[0]['trials']} paired test trials; "
        "labels: decisions off the law)",
        fontsize=9,
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figure, dpi=120)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, nargs="+", default=[1, 2, 4, 8, 16], help="training times")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="one run per seed")
    parser.add_argument("--formulation", default=DEFAULT_FORMULATION, help="the formulation trained")
    parser.add_argument("--trials", type=int, default=400, help="paired test trials per point")
    parser.add_argument("--out", type=Path, default=Path("runs/scaling"), help="where the runs are kept")
    parser.add_argument("--figure", type=Path, default=Path("docs/learning_scaling.png"), help="the figure")
    parser.add_argument("--plot-only", action="store_true", help="score and draw only what --out holds")
    args = parser.parse_args()
    seconds = [m * 60 for m in args.minutes]
    rows = []
    for seed in args.seeds:
        run = args.out / f"{args.formulation}-s{seed}"
        if not args.plot_only:
            train(run, args.formulation, seconds, seed)
        for m, s in zip(args.minutes, seconds, strict=True):
            snapshot = run.with_name(run.name + "-snaps") / snapshot_name(s)
            if snapshot.exists():
                rows.append(
                    {"formulation": args.formulation, "seed": seed, "minutes": m, **score(run, snapshot, args.trials)}
                )
                r = rows[-1]
                print(
                    f"seed {seed} {m:>4g} min ({r['visits'] / 1e6:.0f} M visits): {r['coverage']:.2f} %, "
                    f"{r['minus_base_law']:+.2f} ± {r['minus_base_law_se']:.2f} over {r['base_law']}, margin "
                    f"{r['margin']}, {r['off_law_pct']} % off the law ({r['shared_off_law_pct']} % where shared)",
                    flush=True,
                )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "scaling.json").write_text(json.dumps(rows, indent=1))
    plot(rows, args.figure)
    print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
