"""Human-readable reports of a training run: the terminal summary, ``report.md`` and ``learning_curve.png``, all
written and printed by :func:`emit_run_report` (``up`` and a SLURM job alike).

Input is a :class:`tools.cluster.report.RunReport`: the learner's report (``learner.report.LearnerReport``) and,
from a launcher, its figures beside it (run id, command, settings, recording, supervision, how it was stopped),
read by attribute from the run's end to ``report.md``. Each opens with the result: the final coverage beside the
hand-made controllers' on the same test trials (the learner measures them, ``reference_coverage`` and
``final_reference_coverage``), and ends with the commands that come next. Usage::

    report = RunReport.from_dict(json.loads((run_dir / "report.json").read_text()))
    markdown_path, png_path = write_run_report(report, run_dir)
    print(terminal_summary(report))

Over 400 lines: the terminal summary, ``report.md`` and the chart are one document in three forms, and share its
labels, colours, reference rows and the title that states the result.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from algorithm.files import write_atomic
from algorithm.policy_file import load_policy, scenario_from_header
from algorithm.selection import SavedPolicy
from ennc_ql.command import emit
from ennc_ql.figures import policy_figure
from learner.report import LearnerReport
from monitor.sinks import WEB_VIEWER, WEB_VIEWER_WHY, has_display
from monitor.style import REFERENCES as STYLES
from sim.controllers import COMPASS_NAMES
from sim.formulation import FORMULATIONS
from sim.rollout import WITHIN_NOISE, within_noise
from tools.cluster.report import Interruption, RunReport

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from tools.cluster import RunSummary

REPORT_MD = "report.md"
LEARNING_CURVE_PNG = "learning_curve.png"
REFERENCE_NOTES = {
    "a-cmommt": "hand-made, tuned on training trials; reads only what its robots sense or are told",
    "force-recall": "the tuned force law on frame11d-recall's information: the state and the robot's remembered target",
    "force-6d-shared": "A-CMOMMT's force law fed the 6-D state and the shared-observation flags, tuned",
    "a-cmommt-public": "hand-made; the public code's untuned parameters (teammate-observed weight 0.25)",
    "force-6d": "A-CMOMMT's force law fed the paper's 6-D state",
    "local": "hand-made; attraction to the targets in view, no cooperation",
    "random": "a random compass move every 5 steps",
    "a-cmommt-oracle": "oracle, not a rival: reads true target positions that no robot senses",
}
"""Every hand-made reference, in the order a result lists them (strongest first), with what it is."""
LEARNED_COLOUR = "#000000"
"""The learned policy in the charts: Okabe and Ito's black (the viewer's yellow would vanish on white)."""


def _coverage(value: float | None) -> str:
    return "–" if value is None else f"{value:.2f} %"


def _label(name: str) -> str:
    return STYLES[name][0] if name in STYLES else name


def _colour(name: str) -> str:
    rgb = STYLES[name][1] if name in STYLES else (150, 150, 150)
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def _references(levels: Mapping[str, float]) -> list[tuple[str, float]]:
    """(name, coverage) in the order of :data:`REFERENCE_NOTES`, then any other controller."""
    order = [n for n in REFERENCE_NOTES if n in levels] + [n for n in levels if n not in REFERENCE_NOTES]
    return [(name, float(levels[name])) for name in order]


def _formulation(report: RunReport) -> str | None:
    if report.launch is None or not report.launch.config.formulation:
        return None
    return report.launch.config.formulation


def _stop(report: RunReport) -> Interruption | None:
    return None if report.launch is None else report.launch.interrupted


def interruption(report: RunReport) -> str | None:
    """How a run that was stopped by a signal ended, in one line; None for a run that ran its course."""
    stop = _stop(report)
    if stop is None:
        return None
    how = (
        "the learner checkpointed and wrote its report"
        if stop.learner == "finished"
        else "the learner was killed: the figures are those of its last checkpoint"
    )
    return f"interrupted by {stop.signal} at {stop.at_s:.0f}/{stop.duration_s:g} s of training; {how}"


def headline(report: RunReport) -> list[str]:
    """The result in a few lines: the final figure, its references on the same trials, the paired difference from
    A-CMOMMT and how thickly each team covers its targets."""
    ours = report.learner
    final = ours.final_coverage_mean
    if final is None and _stop(report) is not None and ours.policy_version:
        curve = ours.coverage_curve
        last = f"; its last evaluation: {curve[-1][1]:.2f} % at {curve[-1][0]:.0f} s" if curve else ""
        return [f"result so far: policy version {ours.policy_version}, not scored at the end (stopped){last}"]
    if final is None and _stop(report) is not None:
        return ["result so far: no policy yet (stopped before the first fit, which waits for --learner-min-tuples)"]
    if final is None:
        return ["result: no policy was learned (the first fit waits for --learner-min-tuples tuples)"]
    formulation = _formulation(report)
    trials = ours.final_eval_trials
    what = f", formulation {formulation}" if formulation else ""
    comparison = ours.final_comparison
    learned = comparison.get("learned") or {}
    base = ours.base_law or "a-cmommt"
    lines = []
    if base in comparison:
        lines.append(f"learned - {_label(base)} (its base law): {_paired(comparison[base])} (paired, {trials} trials)")
    if "off_law_pct" in learned:
        shared, shared_off = learned.get("shared_decisions_pct", 0.0), learned.get("shared_off_law_pct", 0.0)
        lines.append(
            f"decisions off the law: {learned['off_law_pct']:.1f} %; where a teammate shared the robot's targets "
            f"({shared:.1f} % of the decisions): {shared_off:.1f} %"
        )
    team = ours.team_table
    if team:
        lines.append(
            f"each robot on its own table (option 2, saved) - the rows merged into one team table: {_team(team)} "
            f"(team table {team['coverage']:.2f} %)"
        )
    lines.append(f"the learned policy observes {final:.2f} % of the targets ({trials} seeded test trials{what})")
    references = sorted(
        ((n, float(row["coverage"])) for n, row in comparison.items() if n != "learned"), key=lambda r: -r[1]
    ) or _references(ours.final_reference_coverage)
    if references:
        lines.append("on the same trials: " + ", ".join(f"{_label(n)} {v:.2f} %" for n, v in references))
    rival = comparison.get("a-cmommt")
    if rival and base != "a-cmommt":
        lines.append(f"learned - {_label('a-cmommt')}: {_paired(rival)} (paired, {trials} trials)")
    if rival and "robots_per_covered_target" in learned and "robots_per_covered_target" in rival:
        lines.append(
            f"robots per covered target: learned {learned['robots_per_covered_target']:.3f}, {_label('a-cmommt')} "
            f"{rival['robots_per_covered_target']:.3f} (how thickly each team crowds the targets it covers)"
        )
    lines[0] = "result: " + lines[0]
    return lines


def _team(team: Mapping[str, float]) -> str:
    mean, se = team["per_robot_minus"], team["per_robot_minus_se"]
    return f"{mean:+.2f} ± {se:.2f} points" + (WITHIN_NOISE if within_noise(mean, se) else "")


def _paired(row: Mapping[str, float]) -> str:
    mean, se = row["learned_minus"], row["learned_minus_se"]
    return f"{mean:+.2f} ± {se:.2f} points" + (WITHIN_NOISE if within_noise(mean, se) else "")


def next_commands(report: RunReport) -> list[tuple[str, str]]:
    """What a user runs next, as (command line, why): score the policy, open the recording, repeat or go on."""
    run_dir, launch, ours = report.run_dir, report.launch, report.learner
    commands: list[tuple[str, str]] = []
    stop = _stop(report)
    if stop is not None:
        left = stop.duration_s - stop.at_s
        commands.append((stop.resume, f"continue the run from its checkpoint ({left:.0f} s of training left)"))
    if ours.policy_file:
        commands.append(
            (
                f"ennc-ql eval --policy {ours.policy_file} --trials {ours.final_eval_trials}",
                "score the policy again (--seed 1: other trials)",
            )
        )
    recording = None if launch is None or launch.recording is None else launch.recording.path
    if recording:
        if has_display():
            commands.append((f"rerun {recording}", "open the recording in the Rerun viewer"))
        else:
            commands.append((f"{WEB_VIEWER} {recording}", WEB_VIEWER_WHY))
    if launch is not None and launch.command.startswith("sbatch "):
        # Submitting a job script again continues its run; another run is another folder, from the same settings.
        again = f"ennc-ql slurm train --config {run_dir / 'up.toml'} --run-id NEW-ID --submit"
        commands.append((again, "repeat the run as a new job"))
    elif launch is not None and launch.command:
        commands.append((launch.command, "repeat the run exactly"))
    else:
        commands.append(
            (f"ennc-ql learner --run-dir {run_dir} --resume ...", "continue from the checkpoint, with the same flags")
        )
    return commands


def result_rows(report: RunReport) -> list[tuple[str, str]]:
    """The figures of a run as (name, value) pairs, the rows of both the terminal table and ``report.md``."""
    ours = report.learner
    rows = [
        ("run folder", "–" if report.launch is None else report.launch.run_dir),
        ("actors", ", ".join(ours.actors) or "–"),
        ("tuples received", f"{ours.tuples_received:,}"),
        ("duplicates / gaps", f"{ours.duplicates} / {ours.gaps}"),
        ("rejected messages", str(ours.rejected)),
        ("policy version", str(ours.policy_version)),
        ("prototypes per action", str(ours.prototypes_per_action)),
        ("final coverage", _coverage(ours.final_coverage_mean)),
        ("coverage curve", ", ".join(f"{t:.0f}s: {c:.1f}%" for t, c in ours.coverage_curve)),
        ("policy file", str(ours.policy_file)),
    ]
    stops = () if report.launch is None else report.launch.interruptions
    if stops:
        current = _stop(report)
        text = "; ".join(
            f"{i.signal} at {i.at_s:.0f}/{i.duration_s:g} s" + ("" if i == current else ", then resumed") for i in stops
        )
        rows.insert(1, ("interruptions", text))
    saved = ours.saved_policy
    if saved is not None:
        rows.insert(-1, ("saved policy", _saved(saved)))
    team = ours.team_table
    if team:
        rows.insert(
            -1,
            (
                "team table",
                f"the robots' rows merged by their visits: {team['coverage']:.2f} %; each robot on its own row - it: "
                f"{_team(team)}",
            ),
        )
    off_law = ours.final_comparison.get("learned", {}).get("off_law_pct")
    if off_law is not None:
        rows.insert(-1, ("decisions off law", f"{off_law:.1f} % of the learned robots' decisions on the final trials"))
    formulation = _formulation(report)
    if formulation in FORMULATIONS:
        rows.insert(1, ("formulation", f"{formulation} ({FORMULATIONS[formulation].describe()})"))
    return rows


def _saved(saved: SavedPolicy) -> str:
    """Which policy the run saved and why, as the run recorded it, and a margin choice's validation scores."""
    text = f"version {saved.version} of {saved.at_s:.0f} s, {saved.reason}"
    if saved.margin is not None:
        text += f"; law margin {saved.margin:g}"
    choice = saved.choice
    if choice is not None:
        tried = ", ".join(
            f"{m:g} {c:.2f} %" + (f" at {choice.spreads[m]:.3f}" if m in choice.spreads else "")
            for m, c in choice.scores.items()
        )
        text += f" (validation seed {choice.seed}, % observed at robots per covered target: {tried})"
    return text


def results_table(report: RunReport) -> str:
    """The figures of a run, aligned."""
    rows = result_rows(report)
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def terminal_summary(report: RunReport) -> str:
    """What ``ennc-ql up`` prints at the end of a run: the result, the figures, where the report is, and next."""
    stop = interruption(report)
    lines = [*([stop, ""] if stop else []), *headline(report), "", results_table(report), ""]
    if report.report_md:
        lines += [f"report: {report.report_md} (learning curve {report.learning_curve or '–'})", ""]
    commands = next_commands(report)
    width = max(len(line) for line, _ in commands)
    lines += ["next:", *(f"  {line:<{width}}  # {why}" for line, why in commands)]
    return "\n".join(lines)


def _table(header: tuple[str, ...], rows: list[tuple[Any, ...]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return [*lines, ""]


def _result(report: RunReport, curve_png: str) -> list[str]:
    ours = report.learner
    final = ours.final_coverage_mean
    lines = ["## Result", ""]
    if final is None:
        return [*lines, headline(report)[0].removeprefix("result: ").capitalize() + ".", ""]
    trials = ours.final_eval_trials
    formulation = _formulation(report)
    saved = ours.saved_policy
    version = ours.policy_version if saved is None else saved.version
    learned = f"version {version}" + (f", formulation {formulation}" if formulation else "")
    rows = [("**learned policy**", learned, f"**{final:.2f}**")]
    rows += [
        (_label(name), REFERENCE_NOTES.get(name, "hand-made"), f"{value:.2f}")
        for name, value in _references(ours.final_reference_coverage)
    ]
    comparison = ours.final_comparison
    base = ours.base_law or "a-cmommt"
    added = []
    if base in comparison:
        added = [
            f"What learning added over its base law, {_label(base)}: **{_paired(comparison[base])}** (paired "
            f"difference ± s.e., {trials} trials).",
            "",
        ]
    learned_row = comparison.get("learned") or {}
    if "off_law_pct" in learned_row:
        added += [
            f"Its robots left the law on {learned_row['off_law_pct']:.1f} % of their decisions; where a teammate "
            f"shared the robot's targets ({learned_row.get('shared_decisions_pct', 0.0):.1f} % of the decisions), on "
            f"{learned_row.get('shared_off_law_pct', 0.0):.1f} % of them.",
            "",
        ]
    lines += [
        *added,
        f"The learned policy observes **{final:.2f} %** of the targets on {trials} seeded test trials of 1000 steps; "
        "the hand-made controllers on the same trials:",
        "",
        *_table(("policy", "what it is", f"% of targets observed ({trials} trials)"), rows),
        *_spread(comparison, trials),
        f"![the learning curve beside the hand-made controllers' levels]({curve_png})",
        "",
    ]
    return lines


def _spread(comparison: Mapping[str, Mapping[str, float]], trials: int) -> list[str]:
    """Why one policy covers more: how each team spread over the targets, per robot-step, and the learned policy's
    paired difference from each reference."""
    if not comparison:
        return []
    rows = [
        (
            "**learned policy**" if name == "learned" else _label(name),
            f"{row['coverage']:.2f}",
            "" if name == "learned" else _paired(row),
            f"{row['only_shared_pct']:.1f}",
            f"{row['none_in_view_pct']:.1f}",
            f"{row['robots_per_covered_target']:.3f}",
        )
        for name, row in [
            ("learned", comparison["learned"]),
            *(
                (n, comparison[n])
                for n, _ in _references({k: v["coverage"] for k, v in comparison.items() if k != "learned"})
            ),
        ]
    ]
    header = (
        "policy",
        "% observed",
        "learned − it (paired, ± s.e.)",
        "% robot-steps seeing only teammate-watched targets",
        "% robot-steps seeing no target",
        "robots per covered target",
    )
    return [
        f"How each team spreads over the targets on the same {trials} trials: a robot that sees only targets a "
        "teammate also sees adds nothing where it stands; one that sees none is searching.",
        "",
        *_table(header, rows),
    ]


def _throughput(report: RunReport) -> list[str]:
    ours = report.learner
    received, by_actor = ours.tuples_received, ours.tuples_by_actor
    lines = [
        "## Throughput",
        "",
        f"{received:,} tuples in {ours.seconds:.0f} s of training: {ours.tuples_per_s:,.0f} tuples/s "
        f"into the learner's store ({ours.store_size:,} kept, {ours.overwritten:,} overwritten).",
        "",
    ]
    if by_actor:
        rows = [(a, f"{n:,}", f"{100 * n / max(received, 1):.1f} %") for a, n in sorted(by_actor.items())]
        lines += _table(("actor", "tuples", "share"), rows)
    return lines


def _integrity(report: RunReport) -> list[str]:
    ours = report.learner
    rows = [
        ("duplicate batches", ours.duplicates),
        ("sequence gaps (never filled)", ours.gaps),
        ("out-of-order arrivals (filled later unless counted as gaps)", ours.out_of_order),
        ("rejected messages", ours.rejected),
        ("rejected by type", ", ".join(f"{k}: {v}" for k, v in sorted(ours.rejected_by_type.items())) or "–"),
        ("table increments merged / stale", f"{ours.increments} / {ours.stale_increments}"),
        ("policy lag per actor (versions)", ", ".join(f"{a}: {v}" for a, v in sorted(ours.policy_lag.items())) or "–"),
    ]
    return ["## Duplicates, gaps, rejected", "", *_table(("figure", "value"), rows)]


def _move_names(report: RunReport) -> tuple[str, ...]:
    """The names of the policy's own moves: its formulation's action set (relative moves are no compass points)."""
    formulation = _formulation(report)
    if formulation in FORMULATIONS:
        return tuple(FORMULATIONS[formulation].actions.moves)
    return COMPASS_NAMES


def _policy(report: RunReport) -> list[str]:
    ours = report.learner
    sizes = ours.prototypes_per_action
    lines = [
        "## Policy",
        "",
        f"Version {ours.policy_version} after {ours.phase1_fits} phase-1 fit(s); "
        f"policy file `{ours.policy_file}`, checkpoint `{ours.checkpoint}`.",
        "",
    ]
    if sizes:
        lines.append(f"Prototypes per action (mean {sum(sizes) / len(sizes):.1f}):")
        lines.append("")
        lines += _table(_move_names(report)[: len(sizes)], [tuple(sizes)])
    if report.policy_figure:
        name = Path(report.policy_figure).name
        lines += [f"![a test arena under the policy, and its prototypes per action coloured by Q]({name})", ""]
    return lines


def _curve(report: RunReport) -> list[str]:
    curve = report.learner.coverage_curve
    lines = ["## Learning curve", ""]
    if not curve:
        return [*lines, "No evaluation: no policy was learned in this run.", ""]
    trials = report.learner.eval_trials
    lines += [
        f"The policy of the moment on {trials} seeded test trials, every evaluation interval:",
        "",
        *_table(("seconds", "coverage %"), [(f"{t:.0f}", f"{c:.2f}") for t, c in curve]),
    ]
    references = _references(report.learner.reference_coverage)
    if references:
        levels = ", ".join(f"{_label(n)} {v:.2f} %" for n, v in references)
        lines += [f"The hand-made controllers on the same {trials} trials: {levels}.", ""]
    return lines


def markdown_report(report: RunReport, curve_png: str = LEARNING_CURVE_PNG) -> str:
    """``report.md``: the result beside its references, then configuration, figures, the learning curve,
    throughput, integrity and policy, and the commands that come next."""
    launch = report.launch
    title = report.run_dir.name if launch is None else launch.run_id
    stop = interruption(report)
    lines = [f"# ennc-ql run {title}", "", *([f"**{stop[0].upper() + stop[1:]}.**", ""] if stop else [])]
    lines += _result(report, curve_png)
    if launch is not None:
        lines += ["```", launch.command, "```", ""]
    took = f"{report.learner.seconds:.0f} s of training"
    if launch is not None:
        took += f", {launch.wall_seconds:.0f} s in all"
    lines += [f"Learner `{report.learner.learner_id}`, {took}.", ""]
    if launch is not None:
        values = [(f.name, getattr(launch.config, f.name)) for f in dataclasses.fields(launch.config)]
        settings = [(k, f"{v:g}" if isinstance(v, float) else v) for k, v in values]
        lines += ["## Configuration", "", *_table(("setting", "value"), settings)]
    lines += ["## Figures", "", *_table(("figure", "value"), result_rows(report))]
    lines += _curve(report) + _throughput(report) + _integrity(report) + _policy(report)
    lines += ["## Next", "", "```", *(f"{line}    # {why}" for line, why in next_commands(report)), "```", ""]
    return "\n".join(lines)


def learning_curve_figure(report: RunReport) -> Figure:
    """Evaluation coverage against training seconds, titled by the result and the formulation, with the hand-made
    controllers' levels on the same trials: lines on the curve's trials, diamonds on the final figure's."""
    # Imported here: every command line builds up's parser, and matplotlib is needed only once a run has ended. The
    # object-oriented Figure needs no pyplot: no global backend switch, no figure registry to leak into.
    from matplotlib.figure import Figure

    ours = report.learner
    curve = ours.coverage_curve
    duration = ours.seconds if report.launch is None else report.launch.config.duration
    end = float(ours.seconds)
    trials, final_trials = ours.eval_trials, ours.final_eval_trials
    final = ours.final_coverage_mean
    finals = dict(ours.final_reference_coverage)
    fig = Figure(figsize=(10, 4.8))
    ax = fig.subplots()
    xmax = max([float(duration), end, *(t for t, _ in curve)])
    # The final figures side by side just past the curve's end, the learned policy's first: at one x they hid each
    # other wherever they lie within a point of each other.
    step = 0.03 * xmax
    references = _references(ours.reference_coverage)
    at = {name: end + step * (k + 2) for k, name in enumerate(n for n, _ in references if n in finals)}
    for name, level in references:
        label = f"{_label(name)}: {level:.1f} %"
        if name in finals:
            label += f", {finals[name]:.1f} % ◆"
            ax.plot([at[name]], [finals[name]], "D", ms=6, color=_colour(name), label="_nolegend_")
        ax.axhline(level, ls="--", lw=1.2, color=_colour(name), label=label)
    if curve:
        label = "the policy the learner held"
        ax.plot([t for t, _ in curve], [c for _, c in curve], "o-", color=LEARNED_COLOUR, label=label)
    for k, resume in enumerate(ours.resumes):
        label = "resumed from the checkpoint" if k == 0 else "_nolegend_"
        ax.axvline(float(resume["at_s"]), ls=":", lw=1.2, color="#555555", label=label)
    if final is not None:
        saved = ours.saved_policy
        read = "" if saved is None or saved.margin is None else f", margin {saved.margin:g}"
        label = f"saved: the last policy{read}: {final:.2f} % ({final_trials} trials)"
        ax.plot([end + step], [final], "*", ms=15, color=LEARNED_COLOUR, label=label)
    elif not curve:
        ax.text(0.5, 0.5, "no evaluation: no policy was learned", transform=ax.transAxes, ha="center")
    ax.set_xlim(0, (max([xmax, *at.values()]) + step) * 1.02)
    ax.set_ylim(*_y_range([c for _, c in curve] + [v for _, v in references] + list(finals.values()), final))
    ax.set_xlabel("training time (s)")
    ax.set_ylabel("% of targets observed")
    formulation = _formulation(report)
    what = f"formulation {formulation}" if formulation else f"run {report.run_dir.name}"
    ax.set_title(f"{_curve_result(final, finals)}\n{what}", fontsize="medium")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(
            loc="upper left",
            bbox_to_anchor=(1.01, 1.0),
            fontsize="small",
            title=f"on the same {trials} test trials (- -)\nand on {final_trials} (◆ ★)",
            title_fontsize="small",
        )
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def _y_range(values: list[float], final: float | None) -> tuple[float, float]:
    """An axis that fits the figures drawn, in steps of 5 points within 0-100: differences of a few points show."""
    shown = [v for v in [*values, *([] if final is None else [final])] if v is not None]
    if not shown:
        return 0.0, 100.0
    return max(0.0, 5.0 * math.floor((min(shown) - 3.0) / 5.0)), min(100.0, 5.0 * math.ceil((max(shown) + 3.0) / 5.0))


def _curve_result(final: float | None, finals: Mapping[str, float]) -> str:
    """The chart's title: the final figure and its gap to the hand-made controller, on the same trials."""
    if final is None:
        return "no final figure (the run was stopped, or learned no policy)"
    result = f"the learned policy observes {final:.1f} % of the targets"
    if "a-cmommt" in finals:
        gap = final - float(finals["a-cmommt"])
        result += f", {abs(gap):.1f} points {'below' if gap < 0 else 'above'} A-CMOMMT ({finals['a-cmommt']:.1f} %)"
    return result


def learning_curve_png(report: RunReport, path: Path) -> Path:
    """The learning curve as a 1000 x 480 PNG."""
    learning_curve_figure(report).savefig(path, dpi=100)
    return path


def write_run_report(report: RunReport, run_dir: Path) -> tuple[Path, Path]:
    """Write ``report.md`` and ``learning_curve.png`` into ``run_dir``; their paths."""
    png = learning_curve_png(report, run_dir / LEARNING_CURVE_PNG)
    markdown = run_dir / REPORT_MD
    write_atomic(markdown, markdown_report(report, png.name).encode())
    return markdown, png


def emit_run_report(report: LearnerReport, summary: RunSummary, as_json: bool) -> None:
    """The learner's report completed with the launcher's ``summary`` and the policy's figure, written as
    ``report.json``, ``report.md`` and ``learning_curve.png``, and printed (``up`` and a SLURM job alike)."""
    run_dir = summary.run_dir
    run = RunReport(report, summary.figures(report), _policy_figure(report, run_dir))
    markdown, png = write_run_report(run, run_dir)
    run = dataclasses.replace(run, report_md=str(markdown), learning_curve=str(png))
    out = run.to_dict()
    write_atomic(run_dir / "report.json", json.dumps(out, indent=2).encode())
    emit(out, as_json, terminal_summary(run))


def _policy_figure(report: LearnerReport, run_dir: Path) -> str | None:
    """``policy.png`` of the learned policy, if one was learned."""
    if not report.policy_file:
        return None
    policy, header = load_policy(report.policy_file)
    return str(policy_figure(policy, scenario_from_header(header), run_dir / "policy.png"))
