"""The paper's Figure 5 and Figure 6 in one call (``ennc-ql reproduce``).

Usage::

    ennc-ql reproduce --quick --jobs 2
    report = reproduce(Budget.quick(), processes=1, out_dir=Path("runs/reproduce-quick"))
    report["methods"]    # name, coverage_mean, coverage_std, states, runs, paper
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from algorithm.experiments import METHODS, Budget, Outcome
from sim import CONTROLLERS, EvalResult, ScenarioConfig, evaluate, scenario
from tools.progress import ProgressBar
from tools.sweeps.jobs import ONE_AT_A_TIME, Backend, Job, JobsBar
from tools.sweeps.results import write_results

if TYPE_CHECKING:
    from matplotlib.figure import Figure

log = logging.getLogger(__name__)

HAND_MADE_ORDER = ("random", "local", "a-cmommt", "a-cmommt-public", "a-cmommt-oracle", "force-6d", "force-6d-shared")
PAPER: dict[str, dict[str, float | None]] = {
    "random": {"coverage": None, "states": None},
    "local": {"coverage": None, "states": None},
    "a-cmommt": {"coverage": 71.0, "states": None},
    "a-cmommt-public": {"coverage": None, "states": None},
    "a-cmommt-oracle": {"coverage": None, "states": None},
    "force-6d": {"coverage": None, "states": None},
    "force-6d-shared": {"coverage": None, "states": None},
    "vqql-local-16": {"coverage": 59.0, "states": 16},
    "vqql-collab-64": {"coverage": 40.0, "states": 64},
    "vqql-collab-256": {"coverage": 50.0, "states": 256},
    "vqql-collab-1024": {"coverage": 60.0, "states": 1024},
    "vqql-collab-2048": {"coverage": 65.0, "states": 2048},
    "ennc-ql-local": {"coverage": 58.45, "states": 101.9},
    "ennc-ql-collab-option1": {"coverage": 62.32, "states": 183.72},
    "ennc-ql-collab-option2": {"coverage": 66.53, "states": 183.72},
}
"""Figure 5 / Figure 6 of the paper (% of targets observed; states or mean prototypes per action). The paper
gives random and local only as bars below 50%, approximate VQQL values, and no exact A-CMOMMT decimals; the
state-limited force laws (``force-6d``, ``force-6d-shared``) are this project's references, not the paper's."""


def reproduce(
    budget: Budget,
    processes: int,
    out_dir: Path,
    methods: Sequence[str] | None = None,
    backend: Backend = ONE_AT_A_TIME,
) -> dict[str, Any]:
    """Run every method (``processes`` independent learning processes each), write table, JSON and chart.

    ``backend`` runs the learning processes (default: one at a time here). Progress goes to stderr: a bar over the
    jobs (learning processes, then hand-made evaluations) with the latest coverage measured.
    """
    start = time.perf_counter()
    names = list(methods) if methods is not None else method_names()
    unknown = [n for n in names if n not in PAPER]
    if unknown:
        raise ValueError(f"unknown methods {unknown}; known: {', '.join(PAPER)}")
    out_dir.mkdir(parents=True, exist_ok=True)  # a folder that cannot be written fails now, not after the runs
    cfg = scenario()
    todo = [Job(n, budget, seed, cfg) for n in names if n not in CONTROLLERS for seed in range(processes)]
    hand_made = [n for n in names if n in CONTROLLERS]
    with ProgressBar("reproduce", total=len(todo) + len(hand_made), unit="jobs") as bar:
        progress = JobsBar(bar)
        outcomes: dict[str, list[Outcome]] = {job.method: [] for job in todo}
        learned = backend.learn(todo, progress)
        for _, outcome in learned:
            outcomes[outcome.method].append(outcome)
        measured = {name: _hand_made(name, cfg, budget, progress) for name in hand_made}
    runs = {name: sorted(found, key=lambda o: o.seed) for name, found in outcomes.items()}
    rows = [
        _hand_made_row(name, measured[name]) if name in CONTROLLERS else _learned_row(name, runs[name])
        for name in names
    ]
    report = {
        "scenario": cfg.name,
        "processes": processes,
        "test_trials": budget.test_trials,
        "test_steps": budget.test_steps,
        "budget": {
            "arenas": budget.arenas,
            "explore_trials": budget.explore_trials,
            "phase2_trials": budget.phase2_trials,
            "enncql_cycles": budget.phase1.n_cycles,
            "enncql_max_patterns": budget.phase1.max_patterns,
        },
        "methods": rows,
        "seconds": round(time.perf_counter() - start, 1),
    }
    policies = {f"{name}-{o.seed}": (o.policy, cfg) for name, found in runs.items() for o in found}
    write_results(out_dir, report, markdown_table(report), bar_chart(report), "figure5.png", policies)
    return report


def _hand_made(name: str, cfg: ScenarioConfig, budget: Budget, progress: JobsBar) -> EvalResult:
    progress.running(f"{name}: evaluating")
    result = evaluate(cfg, CONTROLLERS[name], budget.test_trials, budget.test_steps, seed=budget.test_seed)
    progress.finished(f"{name}: {result.coverage_mean:.2f}%")
    return result


def _row(name: str, per_run: Sequence[float], states: float | None, per_trial: list[list[float]]) -> dict[str, Any]:
    runs = np.asarray(per_run, dtype=np.float64)
    return {
        "name": name,
        "coverage_mean": round(float(runs.mean()), 3),
        "coverage_std": round(float(runs.std()), 3),
        "states": None if states is None else round(float(states), 2),
        "runs": len(runs),
        "coverage_per_run": [round(float(c), 3) for c in runs],
        "coverage_per_trial": per_trial,
        "paper_coverage": PAPER[name]["coverage"],
        "paper_states": PAPER[name]["states"],
    }


def _hand_made_row(name: str, result: EvalResult) -> dict[str, Any]:
    return _row(name, [result.coverage_mean], None, [[round(float(c), 3) for c in result.coverage_per_trial]])


def _learned_row(name: str, runs: list[Outcome]) -> dict[str, Any]:
    row = _row(
        name,
        [o.coverage_mean for o in runs],
        float(np.mean([o.states for o in runs])),
        [[round(float(c), 3) for c in o.coverage_per_trial] for o in runs],
    )
    row["states_per_run"] = [round(o.states, 2) for o in runs]
    row["tuples_per_run"] = [o.tuples for o in runs]
    row["seconds_per_run"] = [round(o.seconds, 1) for o in runs]
    log.info("%s: %.2f%% ± %.2f over %d processes", name, row["coverage_mean"], row["coverage_std"], len(runs))
    return row


def markdown_table(report: dict[str, Any]) -> str:
    lines = [
        f"Scenario `{report['scenario']}`, {report['processes']} learning process(es) per method, each tested on "
        f"{report['test_trials']} trials of {report['test_steps']} steps with 10 robots and 10 targets.",
        "",
        "| method | coverage % (mean ± std over processes) | states / prototypes per action | paper % | paper states |",
        "|---|---|---|---|---|",
    ]
    for row in report["methods"]:
        states = "–" if row["states"] is None else f"{row['states']:g}"
        paper = "–" if row["paper_coverage"] is None else f"{row['paper_coverage']:g}"
        paper_states = "–" if row["paper_states"] is None else f"{row['paper_states']:g}"
        lines.append(
            f"| {row['name']} | {row['coverage_mean']:.2f} ± {row['coverage_std']:.2f} | {states} | {paper} | "
            f"{paper_states} |"
        )
    return "\n".join(lines) + "\n"


def bar_chart(report: dict[str, Any]) -> Figure:
    """Figure 5: every method's coverage (mean ± std over its processes) beside the paper's."""
    from matplotlib.figure import Figure  # matplotlib loads only when a chart is drawn

    rows = report["methods"]
    x = np.arange(len(rows))
    fig = Figure(figsize=(12, 5))
    ax = fig.subplots()
    ours = [r["coverage_mean"] for r in rows]
    ax.bar(x - 0.2, ours, 0.4, yerr=[r["coverage_std"] for r in rows], label="this reproduction", color="#3b7dd8")
    paper = [np.nan if r["paper_coverage"] is None else r["paper_coverage"] for r in rows]
    ax.bar(x + 0.2, paper, 0.4, label="paper (Fig. 5/6)", color="#bbbbbb")
    ax.set_xticks(x, [r["name"] for r in rows], rotation=35, ha="right")
    ax.set_ylabel("% of targets under observation")
    ax.set_ylim(0, 100)
    ax.set_title(f"CMOMMT ({report['scenario']}): {report['processes']} learning process(es) per method")
    ax.legend()
    fig.tight_layout()
    return fig


def method_names() -> list[str]:
    """Every method ``reproduce`` knows, in the order of its table: the paper's (the neural reference of
    ``ablate`` is not one of them)."""
    return [*HAND_MADE_ORDER, *(m for m in METHODS if m in PAPER)]
