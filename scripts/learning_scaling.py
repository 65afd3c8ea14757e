"""The learning-scaling figure: final coverage on the seeded test trials of the final figure against training time.

Runs ``ennc-ql up --duration D --formulation F --seed S`` one after another (never two at once: each uses every
core of a 2-core machine) for every D, F and S asked for, keeps each run's ``report.json``, and draws the final
coverage against D beside the run-measured A-CMOMMT levels (tuned and public, the same trials). Runs already
in ``--out`` are reused, so the grid can be grown over several sittings::

    python scripts/learning_scaling.py --minutes 1 2 4 8 16 --seeds 0 1 --formulations frame-recall-track paper
    python scripts/learning_scaling.py --plot-only      # redraw from the runs kept in --out

Writes ``--out``/scaling.json (one row per run) and ``--figure`` (default docs/learning_scaling.png).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from monitor.style import ORANGE
from monitor.style import REFERENCES as STYLE
from sim.formulation import DEFAULT_FORMULATION

ENNC_QL = Path(sys.executable).with_name("ennc-ql")
REFERENCES = ("a-cmommt", "a-cmommt-public")


def run_id(formulation: str, minutes: float, seed: int) -> str:
    return f"{formulation}-{minutes:g}min-s{seed}"


def train(out: Path, formulation: str, minutes: float, seed: int) -> dict[str, Any]:
    """One ``up`` run (or the one kept from before): its report."""
    report = out / run_id(formulation, minutes, seed) / "report.json"
    if not report.exists():
        command = [str(ENNC_QL), "up", f"--duration={minutes * 60:g}", f"--formulation={formulation}"]
        command += [f"--seed={seed}", f"--runs={out}", f"--run-id={run_id(formulation, minutes, seed)}", "--json"]
        started = time.monotonic()
        print(" ".join(command), flush=True)
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        print(f"  done in {time.monotonic() - started:.0f} s", flush=True)
    return dict(json.loads(report.read_text()))


def row(formulation: str, minutes: float, seed: int, report: dict[str, Any]) -> dict[str, Any]:
    comparison = report.get("final_comparison") or {}
    return {
        "formulation": formulation,
        "minutes": minutes,
        "seed": seed,
        "final_coverage": report["final_coverage_mean"],
        "tuples": report["tuples_received"],
        "tuples_per_s": report["tuples_per_s"],
        "prototypes": sum(report["prototypes_per_action"]),
        "references": report["final_reference_coverage"],
        "versus_a_cmommt": comparison.get("a-cmommt", {}).get("learned_minus"),
        "versus_a_cmommt_se": comparison.get("a-cmommt", {}).get("learned_minus_se"),
        "robots_per_covered_target": comparison.get("learned", {}).get("robots_per_covered_target"),
        "saved": report.get("saved"),
    }


def plot(rows: list[dict[str, Any]], figure: Path) -> None:
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    # Colours the reference levels do not use (monitor.style gives them theirs).
    colours = iter(["black", tuple(c / 255 for c in ORANGE), "grey"])
    for formulation in dict.fromkeys(r["formulation"] for r in rows):
        mine = [r for r in rows if r["formulation"] == formulation]
        minutes = sorted({r["minutes"] for r in mine})
        finals = [[r["final_coverage"] for r in mine if r["minutes"] == m] for m in minutes]
        means = [float(np.mean(f)) for f in finals]
        seeds = sorted({r["seed"] for r in mine})
        colour = next(colours)
        ax.plot(minutes, means, "o-", color=colour, label=f"ENNC-QL, {formulation} (mean of seeds {seeds})")
        for m, f in zip(minutes, finals, strict=True):
            ax.scatter([m] * len(f), f, s=14, color=colour, alpha=0.45, marker="x")
    for name in REFERENCES:
        levels = [r["references"][name] for r in rows if name in r["references"]]
        if levels:
            label, rgb = STYLE[name]
            colour = tuple(c / 255 for c in rgb)
            ax.axhline(float(np.mean(levels)), linestyle="--", color=colour, label=f"{label} (same trials)")
    ax.set_xscale("log", base=2)
    ax.set_xticks(sorted({r["minutes"] for r in rows}), [f"{m:g}" for m in sorted({r["minutes"] for r in rows})])
    ax.set_xlabel("training time, minutes (ennc-ql up, 2 actors, 2 cores)")
    ax.set_ylabel("final coverage, % of targets observed")
    ax.set_title("ENNC-QL: final coverage against training time (x: one seed)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="center right")
    fig.tight_layout()
    fig.savefig(figure, dpi=120)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, nargs="+", default=[1, 2, 4, 8, 16], help="training times")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="seeds of every training time")
    parser.add_argument("--formulations", nargs="+", default=[DEFAULT_FORMULATION], help="formulations")
    parser.add_argument("--out", type=Path, default=Path("runs/scaling"), help="where the runs are kept")
    parser.add_argument("--figure", type=Path, default=Path("docs/learning_scaling.png"), help="the figure")
    parser.add_argument("--plot-only", action="store_true", help="draw from the runs already in --out")
    args = parser.parse_args()
    rows = []
    for formulation in args.formulations:
        for minutes in args.minutes:
            for seed in args.seeds:
                kept = args.out / run_id(formulation, minutes, seed) / "report.json"
                if args.plot_only and not kept.exists():
                    continue
                rows.append(row(formulation, minutes, seed, train(args.out, formulation, minutes, seed)))
    (args.out / "scaling.json").write_text(json.dumps(rows, indent=1))
    for r in rows:
        refs = ", ".join(f"{k} {v:.2f}" for k, v in r["references"].items() if k in REFERENCES)
        gap, se = r["versus_a_cmommt"], r["versus_a_cmommt_se"]
        versus = "" if gap is None else f", {gap:+.2f} ± {se:.2f} over a-cmommt"
        saved = "" if r["saved"] is None else f", saved v{r['saved']['version']} margin {r['saved']['margin']}"
        print(
            f"{r['formulation']:>18} {r['minutes']:>4g} min seed {r['seed']}: {r['final_coverage']:.2f} %{versus} "
            f"({r['tuples'] / 1e6:.0f} M tuples, {r['prototypes']} prototypes{saved}; {refs})"
        )
    plot(rows, args.figure)
    print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
