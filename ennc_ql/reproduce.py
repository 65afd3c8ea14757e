"""``ennc-ql reproduce``: the paper's Figure 5 and Figure 6 in one command.

Usage::

    report = reproduce(Budget.quick(), processes=1, out_dir=Path("runs/reproduce-quick"))
    report["methods"]    # name, coverage_mean, coverage_std, states, runs, paper
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.experiments import METHODS, Budget, Outcome, Progress, train
from algorithm.policy import LostBehaviour
from algorithm.policy_file import save_policy
from ennc_ql.progress import ProgressBar
from sim import HAND_MADE, EvalResult, ScenarioConfig, evaluate, scenario

log = logging.getLogger(__name__)

HAND_MADE_ORDER = ("random", "local", "a-cmommt", "force-6d", "force-6d-shared")
PAPER: dict[str, dict[str, float | None]] = {
    "random": {"coverage": None, "states": None},
    "local": {"coverage": None, "states": None},
    "a-cmommt": {"coverage": 71.0, "states": None},
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


@dataclass(frozen=True, slots=True)
class Job:
    """One learning process to run: a method under a budget and scenario, tested with a lost-robot behaviour."""

    method: str
    budget: Budget
    seed: int
    scenario: ScenarioConfig
    lost_behaviour: LostBehaviour = "wander"
    variant: int = 0
    """Which of a sweep's variants this process belongs to (``ennc-ql ablate``)."""
    featurizer: str | None = None
    """The learners' state instead of the method's own, if given."""
    reward: str | None = None
    """The learners' reward instead of the method's own, if given."""
    act_every: int | None = None
    """Steps between decisions in the test trials (None: ``action_steps``)."""

    @property
    def label(self) -> str:
        return f"{self.method}[{self.seed}]" if not self.variant else f"{self.method} v{self.variant}[{self.seed}]"

    def run(self, progress: Progress | None = None) -> Outcome:
        spec = METHODS[self.method]
        if self.featurizer is not None:
            spec = dataclasses.replace(spec, featurizer=self.featurizer)
        if self.reward is not None:
            spec = dataclasses.replace(spec, reward=self.reward)
        return train(
            spec,
            self.budget,
            self.seed,
            self.scenario,
            progress,
            lost_behaviour=self.lost_behaviour,
            act_every=self.act_every,
        )


def _train_job(job: Job) -> tuple[Job, Outcome]:
    """One learning process in a worker: one torch thread each, so jobs share the cores instead of fighting."""
    import torch

    torch.set_num_threads(1)
    return job, job.run()


class JobsBar:
    """The bar's state: jobs finished, the running job's stage and the latest coverage measured."""

    def __init__(self, bar: ProgressBar) -> None:
        self.bar = bar
        self.done = 0
        self.latest = ""

    def running(self, status: str) -> None:
        self.bar.show(status=status + (f"; latest {self.latest}" if self.latest else ""))

    def finished(self, message: str) -> None:
        self.done += 1
        self.latest = message
        self.bar.mark(message, n=self.done)


def learn(todo: Sequence[Job], jobs: int, progress: JobsBar) -> list[tuple[Job, Outcome]]:
    """Every learning process of ``todo``, ``jobs`` at a time (in worker processes when more than one)."""
    outcomes: list[tuple[Job, Outcome]] = []
    if jobs > 1 and todo:
        import multiprocessing

        progress.running(f"{len(todo)} learning processes on {jobs} workers")
        with multiprocessing.get_context("spawn").Pool(jobs) as pool:
            for job, outcome in pool.imap_unordered(_train_job, todo):
                outcomes.append((job, outcome))
                progress.finished(f"{job.label}: {outcome.coverage_mean:.2f}%")
                # Workers report nothing until a process ends: the bar can only count what is left.
                progress.running(f"{len(todo) - len(outcomes)} learning processes left")
        return outcomes
    for job in todo:

        def stage(message: str, label: str = job.label) -> None:
            progress.running(f"{label}: {message}")

        outcomes.append((job, job.run(stage)))
        progress.finished(f"{job.label}: {outcomes[-1][1].coverage_mean:.2f}%")
    return outcomes


def reproduce(
    budget: Budget,
    processes: int,
    out_dir: Path,
    methods: Sequence[str] | None = None,
    jobs: int = 1,
) -> dict[str, Any]:
    """Run every method (``processes`` independent learning processes each), write table, JSON and chart.

    ``jobs`` > 1 runs that many learning processes at once in worker processes. Progress goes to stderr: a bar
    over the jobs (learning processes, then hand-made evaluations) with the latest coverage measured.
    """
    start = time.perf_counter()
    names = list(methods) if methods is not None else [*HAND_MADE_ORDER, *METHODS]
    unknown = [n for n in names if n not in PAPER]
    if unknown:
        raise ValueError(f"unknown methods {unknown}; known: {', '.join(PAPER)}")
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = scenario()
    todo = [Job(n, budget, seed, cfg) for n in names if n not in HAND_MADE for seed in range(processes)]
    hand_made = [n for n in names if n in HAND_MADE]
    outcomes: dict[str, list[Outcome]] = {job.method: [] for job in todo}
    hand_made_results: dict[str, EvalResult] = {}
    with ProgressBar("reproduce", total=len(todo) + len(hand_made), unit="jobs") as bar:
        progress = JobsBar(bar)
        for _, outcome in learn(todo, jobs, progress):
            outcomes[outcome.method].append(outcome)
        for name in hand_made:
            progress.running(f"{name}: evaluating")
            result = evaluate(cfg, HAND_MADE[name], budget.test_trials, budget.test_steps, seed=budget.test_seed)
            hand_made_results[name] = result
            progress.finished(f"{name}: {result.coverage_mean:.2f}%")
    rows: list[dict[str, Any]] = []
    for name in names:
        if name in HAND_MADE:
            result = hand_made_results[name]
            per_trial = [round(float(c), 3) for c in result.coverage_per_trial]
            rows.append(_row(name, [result.coverage_mean], None, [per_trial]))
            continue
        runs = sorted(outcomes[name], key=lambda o: o.seed)
        for outcome in runs:
            save_policy(outcome.policy, cfg, out_dir / "policies" / f"{name}-{outcome.seed}.npz")
        row = _row(
            name,
            [o.coverage_mean for o in runs],
            float(np.mean([o.states for o in runs])),
            [[round(float(c), 3) for c in o.coverage_per_trial] for o in runs],
        )
        row["states_per_run"] = [round(o.states, 2) for o in runs]
        row["tuples_per_run"] = [o.tuples for o in runs]
        row["seconds_per_run"] = [round(o.seconds, 1) for o in runs]
        rows.append(row)
        log.info("%s: %.2f%% ± %.2f over %d processes", name, row["coverage_mean"], row["coverage_std"], processes)
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
    (out_dir / "results.json").write_text(json.dumps(report, indent=2))
    (out_dir / "results.md").write_text(markdown_table(report))
    bar_chart(report, out_dir / "figure5.png")
    return report


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


def bar_chart(report: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = report["methods"]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(12, 5))
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
    fig.savefig(path, dpi=110)
    plt.close(fig)
