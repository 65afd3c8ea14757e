"""Human-readable reports of a training run: the terminal table, ``report.md`` and ``learning_curve.png``.

Input is the learner's report (``runs/<id>/report.json``, a :class:`learner.report.LearnerReport` as a dict),
optionally completed by the launcher with ``run_id``, ``run_dir``, ``command``, ``config`` and ``wall_seconds``.
Usage::

    report = json.loads((run_dir / "report.json").read_text())
    markdown_path, png_path = write_run_report(report, run_dir)
    print(results_table(report))
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sim.controllers import COMPASS_NAMES
from sim.features import FORMULATIONS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

REPORT_MD = "report.md"
LEARNING_CURVE_PNG = "learning_curve.png"
HAND_MADE_COVERAGE = {
    "random": 16.60,
    "local": 56.92,
    "force-6d-shared": 69.09,
    "A-CMOMMT": 68.26,
    "A-CMOMMT oracle": 72.14,
}
"""Coverage (%) of the hand-made controllers from ``ennc-ql eval --policy NAME --trials 10 --steps 1000 --seed 0``
(README): the protocol of the learner's own evaluations (10 seeded trials of 1000 steps), so the levels compare
directly with the learning curve; force-6d-shared is the force law on what the shared8d state holds; the oracle
reads target positions no robot senses. A test re-measures them."""
FINAL_REFERENCE = ("A-CMOMMT", 50, 73.07)
"""A-CMOMMT on the final figure's protocol, ``ennc-ql eval --policy a-cmommt --trials 50 --seed 0``: drawn beside
the final policy's figure when that is measured on as many trials (a test re-measures it)."""
_REFERENCE_COLOURS = {
    "random": "#999999",
    "local": "#e69f00",
    "force-6d-shared": "#cc79a7",
    "A-CMOMMT": "#009e73",
    "A-CMOMMT oracle": "#0072b2",
}


def _coverage(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f} %"


def result_rows(report: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The figures of a run as (name, value) pairs, the rows of both the terminal table and ``report.md``."""
    curve = report.get("coverage_curve") or []
    rows = [
        ("run folder", str(report.get("run_dir", "–"))),
        ("actors", ", ".join(report["actors"]) or "–"),
        ("tuples received", f"{report['tuples_received']:,}"),
        ("duplicates / gaps", f"{report['duplicates']} / {report['gaps']}"),
        ("rejected messages", str(report["rejected"])),
        ("policy version", str(report["policy_version"])),
        ("prototypes per action", str(report["prototypes_per_action"])),
        ("final coverage", _coverage(report["final_coverage_mean"])),
        ("coverage curve", ", ".join(f"{t:.0f}s: {c:.1f}%" for t, c in curve)),
        ("policy file", str(report["policy_file"])),
    ]
    formulation = report.get("config", {}).get("formulation")
    if formulation in FORMULATIONS:
        rows.insert(1, ("formulation", f"{formulation} ({FORMULATIONS[formulation].describe()})"))
    return rows


def results_table(report: Mapping[str, Any]) -> str:
    """The table ``ennc-ql up`` prints at the end of a run."""
    rows = result_rows(report)
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _table(header: tuple[str, ...], rows: list[tuple[Any, ...]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return [*lines, ""]


def _throughput(report: Mapping[str, Any]) -> list[str]:
    received = int(report["tuples_received"])
    by_actor: dict[str, int] = report.get("tuples_by_actor") or {}
    lines = [
        "## Throughput",
        "",
        f"{received:,} tuples in {report['seconds']:.0f} s of training: {report['tuples_per_s']:,.0f} tuples/s "
        f"into the learner's store ({report['store_size']:,} kept, {report['overwritten']:,} overwritten).",
        "",
    ]
    if by_actor:
        rows = [(a, f"{n:,}", f"{100 * n / max(received, 1):.1f} %") for a, n in sorted(by_actor.items())]
        lines += _table(("actor", "tuples", "share"), rows)
    return lines


def _integrity(report: Mapping[str, Any]) -> list[str]:
    rejected_by_type: dict[str, int] = report.get("rejected_by_type") or {}
    lag: dict[str, int] = report.get("policy_lag") or {}
    rows = [
        ("duplicate batches", report["duplicates"]),
        ("sequence gaps", report["gaps"]),
        ("rejected messages", report["rejected"]),
        ("rejected by type", ", ".join(f"{k}: {v}" for k, v in sorted(rejected_by_type.items())) or "–"),
        ("table increments merged / stale", f"{report['increments']} / {report['stale_increments']}"),
        ("policy lag per actor (versions)", ", ".join(f"{a}: {v}" for a, v in sorted(lag.items())) or "–"),
    ]
    return ["## Duplicates, gaps, rejected", "", *_table(("figure", "value"), rows)]


def _policy(report: Mapping[str, Any]) -> list[str]:
    sizes: list[int] = report["prototypes_per_action"]
    lines = [
        "## Policy",
        "",
        f"Version {report['policy_version']} after {report['phase1_fits']} phase-1 fit(s); "
        f"policy file `{report['policy_file']}`, checkpoint `{report.get('checkpoint', '–')}`.",
        "",
    ]
    if sizes:
        lines.append(f"Prototypes per action (mean {sum(sizes) / len(sizes):.1f}):")
        lines.append("")
        lines += _table(tuple(COMPASS_NAMES[: len(sizes)]), [tuple(sizes)])
    if report.get("policy_figure"):
        name = Path(str(report["policy_figure"])).name
        lines += ["", f"![a test arena under the policy, and its prototypes per action coloured by Q]({name})"]
    return lines


def markdown_report(report: Mapping[str, Any], curve_png: str = LEARNING_CURVE_PNG) -> str:
    """``report.md``: configuration, results, the coverage curve as a table, throughput, integrity and policy."""
    curve = report.get("coverage_curve") or []
    config: dict[str, Any] = report.get("config") or {}
    title = report.get("run_id") or Path(str(report.get("run_dir", "run"))).name
    lines = [f"# ennc-ql run {title}", ""]
    if "command" in report:
        lines += ["```", str(report["command"]), "```", ""]
    took = f"{report['seconds']:.0f} s of training"
    if "wall_seconds" in report:
        took += f", {report['wall_seconds']:.0f} s in all"
    lines += [f"Learner `{report.get('learner_id', 'learner')}`, {took}.", ""]
    if config:
        settings = [(k, f"{v:g}" if isinstance(v, float) else v) for k, v in config.items()]
        lines += ["## Configuration", "", *_table(("setting", "value"), settings)]
    lines += ["## Results", "", *_table(("figure", "value"), result_rows(report))]
    lines += ["## Learning curve", "", f"![evaluation coverage over training time]({curve_png})", ""]
    if curve:
        lines += _table(("seconds", "coverage %"), [(f"{t:.0f}", f"{c:.2f}") for t, c in curve])
    else:
        lines += ["No evaluation: no policy was learned in this run.", ""]
    references = ", ".join(f"{name} {value:.2f} %" for name, value in HAND_MADE_COVERAGE.items())
    name, trials, level = FINAL_REFERENCE
    lines += [
        f"Hand-made controllers on the same test protocol (10 trials of 1000 steps, seed 0): {references}; "
        f"on the final figure's {trials} trials {name} scores {level:.2f} %.",
        "",
    ]
    lines += _throughput(report) + _integrity(report) + _policy(report)
    return "\n".join(lines)


def learning_curve_figure(report: Mapping[str, Any]) -> Figure:
    """Evaluation coverage against training seconds, with the hand-made controllers' levels as horizontal lines."""
    # Imported here: every command line builds up's parser, and matplotlib is needed only once a run has ended. The
    # object-oriented Figure needs no pyplot: no global backend switch, no figure registry to leak into.
    from matplotlib.figure import Figure

    curve = report.get("coverage_curve") or []
    duration = (report.get("config") or {}).get("duration") or report["seconds"]
    fig = Figure(figsize=(8, 4.5))
    ax = fig.subplots()
    for name, level in HAND_MADE_COVERAGE.items():
        ax.axhline(level, ls="--", lw=1, color=_REFERENCE_COLOURS[name], label=f"{name}, hand-made ({level:.2f} %)")
    if curve:
        ax.plot([t for t, _ in curve], [c for _, c in curve], "o-", color="#3b7dd8", label="learned policy")
    final = report.get("final_coverage_mean")
    if final is not None:
        trials = report.get("final_eval_trials", report.get("eval_trials", 10))
        ax.plot([report["seconds"]], [final], "*", ms=14, color="#d84b3b", label=f"final policy ({trials} test trials)")
        name, reference_trials, level = FINAL_REFERENCE
        if trials == reference_trials:
            ax.plot(
                [report["seconds"]],
                [level],
                "*",
                ms=14,
                color=_REFERENCE_COLOURS[name],
                label=f"{name}, hand-made ({reference_trials} test trials, {level:.2f} %)",
            )
    else:
        ax.text(0.5, 0.5, "no evaluation: no policy was learned", transform=ax.transAxes, ha="center")
    ax.set_xlim(0, max([float(duration), *(t for t, _ in curve)]) * 1.02)
    ax.set_ylim(0, 100)
    ax.set_xlabel("training time (s)")
    ax.set_ylabel(f"% of targets observed ({report.get('eval_trials', 10)} test trials)")
    title = report.get("run_id") or Path(str(report.get("run_dir", ""))).name
    ax.set_title(f"run {title}: {report['tuples_received']:,} tuples from {len(report['actors'])} actor(s)")
    ax.legend(loc="best", fontsize="small")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def learning_curve_png(report: Mapping[str, Any], path: Path) -> Path:
    """The learning curve as an 880 x 495 PNG."""
    learning_curve_figure(report).savefig(path, dpi=110)
    return path


def write_run_report(report: Mapping[str, Any], run_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``learning_curve.png`` into ``run_dir``; their paths."""
    png = learning_curve_png(report, run_dir / LEARNING_CURVE_PNG)
    markdown = run_dir / REPORT_MD
    markdown.write_text(markdown_report(report, png.name))
    return markdown, png
