"""One method under parameter overrides (``ennc-ql ablate``), K learning processes per variant, every policy scored on
the same seeded test trials; a table (mean ± std over processes) and a chart.

Each ``--set KEY=V1[,V2...]`` names a field of :class:`Setup` by its dotted path (``budget.phase2.alpha``,
``budget.phase1.max_classes``, ``scenario.action_steps``, ``scenario.learning_steps``, ``lost_behaviour``, and the
formulation's parts: ``featurizer``, ``reward``, ``actions``, ``trial_rules``, ``act_every``); several
values sweep it, and several ``--set`` sweep their product. Usage::

    ennc-ql ablate ennc-ql-collab-option2 --set budget.phase2.alpha=0.05,0.2 --set scenario.action_steps=3,5 \\
        --processes 3 --jobs 2 --quick
    report = ablate("ennc-ql-collab-option2", [("budget.phase2.alpha", [0.05, 0.2])], Setup(), 3, Path("runs/a"))
    report["variants"][0]["coverage_mean"], report["variants"][0]["references"]["a-cmommt"]

Every variant's row carries the coverage of :data:`REFERENCES` on the same test trials of its scenario, its paired
difference with each of them (the processes' mean per trial less the reference's, ± its standard error over the
trials), and the paper's figure for the method, so a result is read beside what the hand-made controllers and the
paper reach. Every process saves its policy by the learner's rule (:class:`algorithm.selection.SaveRule`): the last
tables, a law action set's read with the law margin that scores best on ``budget.law_margin_trials`` validation
trials (``--set budget.law_margin_trials=0``: the argmax).
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from algorithm.experiments import METHODS, UNUSED_BUDGET, Budget, Outcome
from algorithm.policy import LostBehaviour
from monitor.style import REFERENCES as STYLES
from sim import CONTROLLERS, EvalResult, ScenarioConfig, evaluate
from sim.formulation import Formulation
from tools.config import (
    ConfigError,
    parse_setting,
    replace_setting,
)
from tools.progress import ProgressBar
from tools.sweeps.jobs import ONE_AT_A_TIME, Backend, Job, JobsBar
from tools.sweeps.reproduce import PAPER
from tools.sweeps.results import write_results

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Sweep = list[tuple[str, list[Any]]]
REFERENCES = ("a-cmommt", "a-cmommt-public", "a-cmommt-oracle", "force-6d", "force-6d-shared", "force-recall")
"""Hand-made controllers scored beside every variant: A-CMOMMT tuned on training trials (on what its robots sense or
are told), the public code's untuned A-CMOMMT, the tuned law on true target positions no robot senses (the oracle, a
labelled reference only), and its force law limited to the 6-D state (without, and tuned with, the
shared-observation flags) and to the remembering state of the default formulation (``force-recall``), i.e. what the
learned policy's own state allows a hand-made law."""
PAIRED = "a-cmommt"
"""The reference the table gives every variant's paired difference with (``results.json`` has every reference's)."""


@dataclass(frozen=True, slots=True)
class Setup:
    """Everything a variant may change: the learning budget, the scenario and the test-time acting rule."""

    budget: Budget = field(default_factory=Budget)
    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    lost_behaviour: LostBehaviour = "wander"
    """What a robot that sees no target does in the test trials: wander, stay, or follow the policy."""
    featurizer: str | None = None
    """The learners' state; None: the method's own."""
    reward: str | None = None
    """The learners' reward (``paper``: the state's own); None: the method's own."""
    act_every: int | None = None
    """Steps between a robot's decisions in the test trials; None: ``action_steps``, as it learned."""
    actions: str | None = None
    """The action set; None: the method's own."""
    trial_rules: str = "paper"
    """The learning-trial rules (:data:`sim.formulation.TRIAL_RULES`): ``paper``, or e.g. ``search-on``, a lost
    learner searching on and the time-out bootstrapping [beyond the paper]."""

    def formulation(self, method: str) -> Formulation:
        """What ``method`` learns on in this setup: its own formulation's parts with this setup's over them.
        ``ConfigError`` names an unknown part (the registries' names are checked here, by the formulation), or a law
        margin asked of an action set without the law's move."""
        spec = METHODS[method]
        try:
            formulation = Formulation.of(
                self.featurizer or spec.featurizer,
                self.reward or spec.reward,
                self.actions or spec.actions,
                act_every=self.act_every,
                trial_rules=self.trial_rules,
            )
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        return formulation


def parse_sets(texts: Sequence[str]) -> Sweep:
    """``KEY=V1,V2`` strings as (key, typed values); ``ConfigError`` names the bad one."""
    sweep: Sweep = []
    for text in texts:
        key, sep, values = text.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise ConfigError(f"--set {text!r}: expected KEY=VALUE[,VALUE...]")
        if key in (k for k, _ in sweep):
            raise ConfigError(f"--set {key}: given twice (list every value in one --set)")
        sweep.append((key, [parse_setting(Setup, key, v.strip()) for v in values.split(",")]))
    return sweep


def check_used(method: str, sweep: Sweep) -> None:
    """ConfigError for a swept key that ``method`` never reads: its variants would all be the same."""
    algorithm = METHODS[method].algorithm
    unused = UNUSED_BUDGET.get(algorithm, ())
    for key, _ in sweep:
        part = key.split(".")
        if part[0] == "budget" and len(part) > 1 and part[1] in unused:
            used = ", ".join(f"budget.{f.name}" for f in dataclasses.fields(Budget) if f.name not in unused)
            raise ConfigError(
                f"--set {key}: {method} never reads budget.{part[1]} (a {algorithm} method), so every variant "
                f"would be the same; it reads {used}"
            )


def variants(base: Setup, sweep: Sweep) -> list[tuple[dict[str, Any], Setup]]:
    """Every combination of the swept values, as (overrides, the setup they give); the base alone if none."""
    keys = [k for k, _ in sweep]
    out: list[tuple[dict[str, Any], Setup]] = []
    for combo in itertools.product(*(values for _, values in sweep)):
        overrides = dict(zip(keys, combo, strict=True))
        setup = base
        for key, value in overrides.items():
            setup = replace_setting(setup, key, value)
        out.append((overrides, setup))
    return out


def _label(overrides: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v}" for k, v in overrides.items()) or "as configured"


TestTrials = tuple[ScenarioConfig, int, int, int]
"""What a variant's test trials are: its scenario, and the budget's test trials, steps and seed."""


def _trials(setup: Setup) -> TestTrials:
    budget = setup.budget
    return setup.scenario, budget.test_trials, budget.test_steps, budget.test_seed


def ablate(
    method: str,
    sweep: Sweep,
    base: Setup,
    processes: int,
    out_dir: Path,
    backend: Backend = ONE_AT_A_TIME,
) -> dict[str, Any]:
    """Run every variant ``processes`` times (by ``backend``: default one at a time here); write
    ``results.json``, ``results.md``, ``ablation.png`` and each policy under ``out_dir``; return the report."""
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; learned methods: {', '.join(METHODS)}")
    start = time.perf_counter()
    setups = variants(base, sweep)
    out_dir.mkdir(parents=True, exist_ok=True)  # a folder that cannot be written fails now, not after the runs
    todo = [
        Job(
            method,
            setup.budget,
            seed,
            setup.scenario,
            setup.lost_behaviour,
            variant=i + 1,
            formulation=setup.formulation(method),
        )
        for i, (_, setup) in enumerate(setups)
        for seed in range(processes)
    ]
    with ProgressBar("ablate", total=len(todo) + len(setups), unit="jobs") as bar:
        progress = JobsBar(bar)
        results = backend.learn(todo, progress)
        references = _references([setup for _, setup in setups], progress)
    runs = {
        i: sorted((o for job, o in results if job.variant == i), key=lambda o: o.seed)
        for i in range(1, len(setups) + 1)
    }
    rows = [
        _row(i, overrides, runs[i], references[_trials(setup)]) for i, (overrides, setup) in enumerate(setups, start=1)
    ]
    # The test trials as the variants ran them (a --set of budget.test_* changes them), the base's where they differ.
    tested = {_trials(setup)[1:] for _, setup in setups}
    n_trials, n_steps, seed = tested.pop() if len(tested) == 1 else _trials(base)[1:]
    report = {
        "method": method,
        "processes": processes,
        "test_trials": n_trials,
        "test_steps": n_steps,
        "test_seed": seed,
        "paper_coverage": PAPER.get(method, {}).get("coverage"),
        "paper_states": PAPER.get(method, {}).get("states"),
        "sweep": [[k, vs] for k, vs in sweep],
        "variants": rows,
        "seconds": round(time.perf_counter() - start, 1),
    }
    policies = {
        f"v{i}-{o.seed}": (o.policy, setup.scenario) for i, (_, setup) in enumerate(setups, start=1) for o in runs[i]
    }
    write_results(out_dir, report, markdown_table(report), chart(report), "ablation.png", policies)
    return report


def _references(setups: list[Setup], progress: JobsBar) -> dict[TestTrials, dict[str, EvalResult]]:
    """:data:`REFERENCES` on each variant's test trials, measured once per distinct set of trials."""
    references: dict[TestTrials, dict[str, EvalResult]] = {}
    for setup in setups:
        trials = _trials(setup)
        if trials not in references:
            progress.running("the references on the variant's test trials")
            cfg, n, steps, seed = trials
            references[trials] = {name: evaluate(cfg, CONTROLLERS[name], n, steps, seed) for name in REFERENCES}
        progress.finished(", ".join(f"{name} {value.coverage_mean:.2f}%" for name, value in references[trials].items()))
    return references


def paired(runs: list[Outcome], reference: EvalResult) -> list[float | None]:
    """The variant's processes against a reference on the same trials, rounded: the mean over trials of (the
    processes' mean coverage on the trial − the reference's) and its standard error over trials (None with one
    trial). The spread between processes is the row's std, not in this error."""
    diff, se = EvalResult(np.mean([o.coverage_per_trial for o in runs], axis=0)).minus(reference)
    return [round(diff, 3), None if np.isnan(se) else round(se, 3)]


def _row(i: int, overrides: dict[str, Any], runs: list[Outcome], references: dict[str, EvalResult]) -> dict[str, Any]:
    coverage = np.array([o.coverage_mean for o in runs])
    margins = [o.policy.law_margin for o in runs if o.policy is not None]
    return {
        "variant": i,
        "overrides": dict(overrides),
        "label": _label(overrides),
        "coverage_mean": round(float(coverage.mean()), 3),
        "coverage_std": round(float(coverage.std()), 3),
        "coverage_per_run": [round(float(c), 3) for c in coverage],
        "states_per_run": [round(o.states, 2) for o in runs],
        "tuples_per_run": [o.tuples for o in runs],
        "seconds_per_run": [round(o.seconds, 1) for o in runs],
        "law_margin_per_run": margins,
        "references": {name: round(r.coverage_mean, 3) for name, r in references.items()},
        "paired": {name: paired(runs, r) for name, r in references.items()},
    }


def markdown_table(report: dict[str, Any]) -> str:
    paper = report["paper_coverage"]
    lines = [
        f"`{report['method']}`, {report['processes']} learning process(es) per variant, each tested on "
        f"{report['test_trials']} trials of {report['test_steps']} steps (seed {report['test_seed']})"
        + (f"; the paper reports {paper:g} %." if paper is not None else "."),
        "",
        "| variant | coverage % (mean ± std) | per process | prototypes per action | "
        + f"− {PAIRED}, paired ± s.e. | "
        + " | ".join(f"{name} %" for name in REFERENCES)
        + " |",
        "|---|---|---|---|---|" + "---|" * len(REFERENCES),
    ]
    for row in report["variants"]:
        per_run = ", ".join(f"{c:.1f}" for c in row["coverage_per_run"])
        states = float(np.mean(row["states_per_run"])) if row["states_per_run"] else float("nan")
        diff, se = row["paired"][PAIRED]
        lines.append(
            f"| {row['label']} | {row['coverage_mean']:.2f} ± {row['coverage_std']:.2f} | {per_run} | {states:.0f} | "
            + (f"{diff:+.2f}" if se is None else f"{diff:+.2f} ± {se:.2f}")
            + " | "
            + " | ".join(f"{row['references'][name]:.2f}" for name in REFERENCES)
            + " |"
        )
    return "\n".join(lines) + "\n"


def chart(report: dict[str, Any]) -> Figure:
    """Every variant's coverage (mean ± std over its processes) beside the references' and the paper's."""
    from matplotlib.figure import Figure  # matplotlib loads only when a chart is drawn

    rows = report["variants"]
    x = np.arange(len(rows))
    fig = Figure(figsize=(max(6.0, 1.6 * len(rows) + 2), 5))
    ax = fig.subplots()
    means = [r["coverage_mean"] for r in rows]
    ax.bar(x, means, 0.6, yerr=[r["coverage_std"] for r in rows], color="#3b7dd8", capsize=4)
    for i, row in enumerate(rows):
        ax.text(i, row["coverage_mean"] + row["coverage_std"] + 1.5, f"{row['coverage_mean']:.1f}", ha="center")
    for name, style in zip(REFERENCES, ("--", (0, (3, 1)), (0, (5, 1, 1, 1)), "-.", ":", (0, (1, 1))), strict=True):
        color = tuple(c / 255 for c in STYLES[name][1])
        for value in sorted({r["references"][name] for r in rows}):
            ax.axhline(value, color=color, linestyle=style, linewidth=1)
        ax.plot([], [], color=color, linestyle=style, label=f"{STYLES[name][0]}, same trials")
    if report["paper_coverage"] is not None:
        ax.axhline(report["paper_coverage"], color="#555555", linestyle=(0, (1, 4)), label="paper")
    # One override per line under its bar, by its last key part: the full keys are in the table.
    ticks = [
        "\n".join(f"{k.rsplit('.', 1)[-1]}={v}" for k, v in r["overrides"].items()) or "as configured" for r in rows
    ]
    ax.set_xticks(x, ticks, fontsize="small")
    ax.set_ylabel("% of targets under observation")
    ax.set_ylim(0, 100)
    ax.set_title(f"{report['method']}: {report['processes']} learning process(es) per variant")
    ax.legend(loc="upper left", fontsize="small")
    fig.tight_layout()
    return fig
