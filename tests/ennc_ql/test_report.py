"""Run reports: the terminal summary and ``report.md`` open with the result beside the references the learner
measured on the same trials and end with the next commands; ``learning_curve.png`` draws those references."""

from __future__ import annotations

import dataclasses
import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.image import imread

from actors.config import ActorConfig
from ennc_ql import report as written
from ennc_ql.cli import build_parser
from learner.config import LearnerConfig
from learner.report import LearnerReport
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS
from tools.cluster import (
    UP_PRESETS,
    Interruption,
    ProcessRun,
    RecordingFigures,
    Restart,
    RunReport,
    RunSummary,
    UpConfig,
    child_configs,
    write_configs,
)
from tools.config import ConfigError, load_config

# Levels no constant holds: the charts and tables must take them from the report.
CURVE_REFERENCES = {
    "random": 16.5,
    "local": 55.25,
    "a-cmommt": 66.75,
    "a-cmommt-public": 64.25,
    "a-cmommt-oracle": 71.5,
    "force-6d": 63.0,
    "force-6d-shared": 67.5,
}
FINAL_REFERENCES = {
    "random": 16.75,
    "local": 57.0,
    "a-cmommt": 72.25,
    "a-cmommt-public": 69.5,
    "a-cmommt-oracle": 74.5,
    "force-6d": 69.75,
    "force-6d-shared": 71.0,
}
SPREAD = {"only_shared_pct": 40.25, "none_in_view_pct": 12.5, "robots_per_covered_target": 1.375}
FINAL_COMPARISON = {
    "learned": {"coverage": 61.234, **SPREAD},
    **{
        name: {"coverage": value, **SPREAD, "learned_minus": 61.234 - value, "learned_minus_se": 0.625}
        for name, value in FINAL_REFERENCES.items()
    },
    "a-cmommt": {
        "coverage": 72.25,
        "only_shared_pct": 5.5,
        "none_in_view_pct": 30.0,
        "robots_per_covered_target": 1.0625,
        "learned_minus": -11.016,
        "learned_minus_se": 0.5,
    },
}


# The reports below are report.json as a launcher writes it; each is read back typed, as up's resume reads one.
def write_run_report(report: dict[str, Any], run_dir: Path) -> tuple[Path, Path]:
    return written.write_run_report(RunReport.from_dict(report), run_dir)


def terminal_summary(report: dict[str, Any]) -> str:
    return written.terminal_summary(RunReport.from_dict(report))


def markdown_report(report: dict[str, Any]) -> str:
    return written.markdown_report(RunReport.from_dict(report))


def learning_curve_figure(report: dict[str, Any]) -> Any:
    return written.learning_curve_figure(RunReport.from_dict(report))


def next_commands(report: dict[str, Any]) -> list[tuple[str, str]]:
    return written.next_commands(RunReport.from_dict(report))


def run_report(run_dir: Path) -> dict[str, Any]:
    """A report as ``ennc-ql up`` leaves it: a LearnerReport as a dict plus the launcher's keys."""
    return {
        "learner_id": "learner",
        "actors": ["actor-0", "actor-1"],
        "live_actors": ["actor-0", "actor-1"],
        "tuples_received": 2_457_600,
        "tuples_by_actor": {"actor-0": 1_228_800, "actor-1": 1_228_800},
        "tuples_per_s": 5120.0,
        "policy_version": 37,
        "phase1_fits": 1,
        "prototypes_per_action": [201, 188, 247, 230, 196, 215, 260, 221],
        "duplicates": 3,
        "gaps": 1,
        "out_of_order": 12,
        "rejected": 2,
        "rejected_by_type": {"ExperienceBatch": 2},
        "increments": 412,
        "stale_increments": 5,
        "store_size": 400_000,
        "overwritten": 2_057_600,
        "policy_lag": {"actor-0": 0, "actor-1": 1},
        "final_coverage_mean": 61.234,
        "final_eval_trials": 50,
        "eval_trials": 10,
        "coverage_curve": [[95.2, 48.5], [215.7, 57.125], [337.9, 60.4], [480.3, 61.234]],
        "reference_coverage": CURVE_REFERENCES,
        "final_reference_coverage": FINAL_REFERENCES,
        "final_comparison": FINAL_COMPARISON,
        "policy_file": str(run_dir / "policy.npz"),
        "checkpoint": str(run_dir / "checkpoint.npz"),
        "seconds": 480.31,
        "run_id": "20260101-120000",
        "run_dir": str(run_dir),
        "command": f"ennc-ql up --config {run_dir / 'up.toml'}",
        "config": {"actors": 2, "duration": 480.0, "seed": 0, "formulation": "shared-difference"},
        "wall_seconds": 512.4,
        "recording": {"path": str(run_dir / "recording.rrd")},
    }


def dark_pixels(image: np.ndarray) -> int:
    """Pixels of the learned curve's colour, black (text is anti-aliased grey at this size)."""
    return int((image[..., :3] < 0.05).all(axis=-1).sum())


def test_markdown_report_opens_with_the_result_beside_its_references(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    markdown_path, png_path = write_run_report(report, tmp_path)
    assert (markdown_path, png_path) == (tmp_path / "report.md", tmp_path / "learning_curve.png")
    lines = markdown_path.read_text().splitlines()
    assert lines[:3] == ["# ennc-ql run 20260101-120000", "", "## Result"]
    assert lines[4] == (
        "What learning added over its base law, A-CMOMMT: **-11.02 ± 0.50 points** (paired difference ± s.e., 50 "
        "trials)."
    )
    assert lines[6].startswith("The learned policy observes **61.23 %** of the targets on 50 seeded test trials")
    table = lines[lines.index("| policy | what it is | % of targets observed (50 trials) |") :][2:10]
    assert table == [
        "| **learned policy** | version 37, formulation shared-difference | **61.23** |",
        "| A-CMOMMT | hand-made, tuned on training trials; reads only what its robots sense or are told | 72.25 |",
        "| force law, 6-D state + shared flags | A-CMOMMT's force law fed the 6-D state and the shared-observation "
        "flags, tuned | 71.00 |",
        "| A-CMOMMT, public untuned parameters | hand-made; the public code's untuned parameters (teammate-observed "
        "weight 0.25) | 69.50 |",
        "| force law on the 6-D state | A-CMOMMT's force law fed the paper's 6-D state | 69.75 |",
        "| local | hand-made; attraction to the targets in view, no cooperation | 57.00 |",
        "| random | a random compass move every 5 steps | 16.75 |",
        "| A-CMOMMT oracle (true positions) | oracle, not a rival: reads true target positions that no robot senses "
        "| 74.50 |",
    ]
    # Why one covers more: each team's spread over the targets, the learned policy's paired difference from each.
    spread = lines[lines.index(next(line for line in lines if line.startswith("| policy | % observed"))) :][2:10]
    assert spread[0] == "| **learned policy** | 61.23 |  | 40.2 | 12.5 | 1.375 |"
    assert spread[1] == "| A-CMOMMT | 72.25 | -11.02 ± 0.50 points | 5.5 | 30.0 | 1.062 |"
    assert spread[-1].startswith("| A-CMOMMT oracle (true positions) | 74.50 | -13.27 ± 0.62 points |")
    assert "![the learning curve beside the hand-made controllers' levels](learning_curve.png)" in lines


def test_markdown_report_carries_the_figures_and_ends_with_the_next_commands(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("DISPLAY", ":0")  # where a viewer's window can open: the recording opens in it
    report = run_report(tmp_path)
    text = write_run_report(report, tmp_path)[0].read_text()
    assert "| duration | 480 |" in text and "| formulation | shared-difference |" in text
    assert "| tuples received | 2,457,600 |" in text and "| final coverage | 61.23 % |" in text
    for row in ("| 95 | 48.50 |", "| 216 | 57.12 |", "| 338 | 60.40 |", "| 480 | 61.23 |"):
        assert row in text
    assert "The hand-made controllers on the same 10 trials: A-CMOMMT 66.75 %, force law, 6-D state" in text
    assert "| actor-0 | 1,228,800 | 50.0 % |" in text
    assert "5,120 tuples/s" in text and "2,057,600 overwritten" in text
    assert "| duplicate batches | 3 |" in text and "| sequence gaps (never filled) | 1 |" in text
    assert "| out-of-order arrivals (filled later unless counted as gaps) | 12 |" in text
    assert "| rejected by type | ExperienceBatch: 2 |" in text
    assert "| policy lag per actor (versions) | actor-0: 0, actor-1: 1 |" in text
    assert "| 201 | 188 | 247 | 230 | 196 | 215 | 260 | 221 |" in text and "mean 219.8" in text
    assert text.endswith(
        "## Next\n\n```\n"
        f"ennc-ql eval --policy {tmp_path / 'policy.npz'} --trials 50    # score the policy again (--seed 1: other "
        "trials)\n"
        f"rerun {tmp_path / 'recording.rrd'}    # open the recording in the Rerun viewer\n"
        f"ennc-ql up --config {tmp_path / 'up.toml'}    # repeat the run exactly\n"
        "```\n"
    )


def test_terminal_summary_opens_with_the_result_and_ends_with_what_comes_next(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("DISPLAY", ":0")
    lines = terminal_summary({**run_report(tmp_path), "report_md": str(tmp_path / "report.md")}).splitlines()
    # A report without base_law (another formulation's, or an older one): A-CMOMMT is the base it is read against.
    assert lines[0] == "result: learned - A-CMOMMT (its base law): -11.02 ± 0.50 points (paired, 50 trials)"
    assert lines[1] == (
        "the learned policy observes 61.23 % of the targets (50 seeded test trials, formulation shared-difference)"
    )
    assert lines[2] == (
        "on the same trials: A-CMOMMT oracle (true positions) 74.50 %, A-CMOMMT 72.25 %, force law, 6-D state + "
        "shared flags 71.00 %, force law on the 6-D state 69.75 %, A-CMOMMT, public untuned parameters 69.50 %, "
        "local 57.00 %, random 16.75 %"
    )  # sorted by score
    assert lines[3] == (
        "robots per covered target: learned 1.375, A-CMOMMT 1.062 (how thickly each team crowds the targets it covers)"
    )
    assert "coverage curve         95s: 48.5%, 216s: 57.1%, 338s: 60.4%, 480s: 61.2%" in lines
    assert "duplicates / gaps      3 / 1" in lines
    assert any(line.startswith(f"report: {tmp_path / 'report.md'}") for line in lines)
    assert lines[-4] == "next:"
    assert lines[-3].startswith(f"  ennc-ql eval --policy {tmp_path / 'policy.npz'} --trials 50")
    assert lines[-2].startswith(f"  rerun {tmp_path / 'recording.rrd'} ")
    assert lines[-1].startswith(f"  ennc-ql up --config {tmp_path / 'up.toml'} ")
    assert lines[-1].endswith("# repeat the run exactly")


def test_learning_curve_is_titled_by_its_result_and_draws_the_measured_references(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    ax = learning_curve_figure(report).axes[0]
    gap = f"{FINAL_REFERENCES['a-cmommt'] - 61.234:.1f} points below A-CMOMMT ({FINAL_REFERENCES['a-cmommt']:.1f} %)"
    assert ax.get_title() == f"the learned policy observes 61.2 % of the targets, {gap}\nformulation shared-difference"
    lines = {line.get_label(): line for line in ax.get_lines() if not line.get_label().startswith("_")}
    np.testing.assert_allclose(np.asarray(lines["the policy the learner held"].get_xydata()), report["coverage_curve"])
    [[x, y]] = lines["saved: the last policy: 61.23 % (50 trials)"].get_xydata().tolist()
    assert y == 61.234 and x > report["seconds"]
    assert lines["A-CMOMMT: 66.8 %, 72.2 % ◆"].get_ydata() == [66.75, 66.75]
    assert lines["A-CMOMMT oracle (true positions): 71.5 %, 74.5 % ◆"].get_ydata() == [71.5, 71.5]
    assert len(lines) == 2 + len(CURVE_REFERENCES)
    # The levels on the final trials are diamonds at the end of training, one per reference.
    # The levels on the final trials are diamonds past the end of training, one per reference, each at an x of its
    # own so that none hides another; the axis fits the figures, in steps of 5 points.
    marks = [line for line in ax.get_lines() if line.get_marker() in ("D", "*")]
    assert sorted(line.get_ydata()[0] for line in marks if line.get_marker() == "D") == sorted(
        FINAL_REFERENCES.values()
    )
    assert len({line.get_xdata()[0] for line in marks}) == len(marks) == 1 + len(FINAL_REFERENCES)
    assert ax.get_xlim()[1] > max(line.get_xdata()[0] for line in marks)
    low, high = ax.get_ylim()
    assert low % 5 == high % 5 == 0 and 0 < low <= 48.5 - 3 and 74.5 + 3 <= high < 100


def test_learning_curve_png_is_an_image_of_the_chart(tmp_path: Path) -> None:
    _, png_path = write_run_report(run_report(tmp_path), tmp_path)
    image = imread(png_path)
    assert image.shape == (480, 1000, 4)  # 10 x 4.8 inches at 100 dpi
    assert dark_pixels(image) > 300  # the learned policy's markers, line and star


def test_a_run_without_a_policy_still_gets_a_report(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    report.update(
        coverage_curve=[],
        final_coverage_mean=None,
        prototypes_per_action=[],
        policy_file=None,
        reference_coverage={},
        final_reference_coverage={},
    )
    markdown_path, png_path = write_run_report(report, tmp_path)
    text = markdown_path.read_text()
    assert "## Result\n\nNo policy was learned (the first fit waits for --learner-min-tuples tuples).\n" in text
    assert "| final coverage | – |" in text and "No evaluation: no policy was learned" in text
    assert "Prototypes per action" not in text and "ennc-ql eval" not in text
    assert learning_curve_figure(report).axes[0].get_lines() == []
    assert imread(png_path).shape == (480, 1000, 4)
    assert terminal_summary(report).splitlines()[0].startswith("result: no policy was learned")


def test_the_learner_report_alone_is_enough(tmp_path: Path) -> None:
    """The launcher's keys are optional: a learner run on its own can be reported, and resumed."""
    report = run_report(tmp_path)
    for key in ("run_id", "command", "config", "wall_seconds", "recording"):
        del report[key]
    text = write_run_report(report, tmp_path)[0].read_text()
    assert text.startswith(f"# ennc-ql run {tmp_path.name}\n")
    assert "## Configuration" not in text and "| tuples received | 2,457,600 |" in text
    assert f"ennc-ql learner --run-dir {tmp_path} --resume ...    # continue from the checkpoint" in text


def test_up_writes_every_process_configuration_and_they_load_back(tmp_path: Path) -> None:
    argv = ["up", "--actors", "3", "--duration", "60", "--learner-store-capacity", "1000000", "--actor-learn", "0-4"]
    args = build_parser().parse_args(argv)
    config = load_config(UpConfig, args=args, defaults=UP_PRESETS)
    assert config.learner.store_capacity == 1_000_000  # the flag beats up's preset
    assert config.actor.arenas == UP_PRESETS["actor.arenas"] != ActorConfig().arenas  # the preset beats the default
    learner, actors = child_configs(config)
    write_configs(config, learner, actors, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "actor-0.toml",
        "actor-1.toml",
        "actor-2.toml",
        "learner.toml",
        "up.toml",
    ]
    assert load_config(UpConfig, file=tmp_path / "up.toml") == config
    assert load_config(LearnerConfig, file=tmp_path / "learner.toml") == learner
    assert learner.duration == 60.0 and learner.seed == 0
    for i, actor in enumerate(actors):
        assert load_config(ActorConfig, file=tmp_path / f"actor-{i}.toml") == actor
        assert actor.actor_id == f"actor-{i}" and actor.learn == (0, 1, 2, 3, 4)
    # The children's own command lines read the same files; a flag given there still wins.
    child = build_parser().parse_args(["actor", "--config", str(tmp_path / "actor-1.toml"), "--arenas", "7"])
    assert load_config(ActorConfig, file=child.config, args=child) == dataclasses.replace(actors[1], arenas=7)
    # The formulation sets the state, the reward and the action set of every process at once: the default one, or
    # the paper's; up.toml says it once, and every table of it says the same.
    chosen = FORMULATIONS[DEFAULT_FORMULATION]
    assert UpConfig().formulation == LearnerConfig().formulation == ActorConfig().formulation == DEFAULT_FORMULATION
    assert learner.resolved == chosen and {a.resolved.names for a in actors} == {chosen.names}
    toml = tomllib.loads((tmp_path / "up.toml").read_text())
    assert toml["formulation"] == DEFAULT_FORMULATION
    # What up sets in every process itself is said once, at the top, never again in a table that up would override.
    assert not {"formulation", "featurizer", "reward", "act_every", "seed", "duration"} & set(toml["learner"])
    assert not {"formulation", "featurizer", "reward", "actor_id", "seed", "duration"} & set(toml["actor"])
    (tmp_path / "seeded.toml").write_text("seed = 1\n[actor]\nseed = 4\n")
    with pytest.raises(ConfigError, match=r"actor.seed = 4: up sets every actor's seed itself, from seed"):
        load_config(UpConfig, file=tmp_path / "seeded.toml")
    (tmp_path / "same.toml").write_text("seed = 4\n[actor]\nseed = 4\n[learner]\nseed = 0\n")  # as up sets it
    assert load_config(UpConfig, file=tmp_path / "same.toml").seed == 4
    paper = load_config(UpConfig, args=build_parser().parse_args(["up", "--formulation", "paper"]), defaults=UP_PRESETS)
    learner, actors = child_configs(paper)
    assert {p.formulation for p in (paper.learner, paper.actor, learner, *actors)} == {"paper"}
    assert {p.resolved.names[:2] for p in (learner, *actors)} == {("collab6d", "eq2")}
    assert learner.resolved.act_every is None
    (tmp_path / "mixed.toml").write_text('formulation = "paper"\n[learner]\nreward = "difference"\n')
    with pytest.raises(ConfigError, match=r"learner.reward: up gives every process the formulation it names"):
        load_config(UpConfig, file=tmp_path / "mixed.toml")
    (tmp_path / "best.toml").write_text('formulation = "best"\n')
    with pytest.raises(ConfigError, match="formulation: unknown 'best'"):
        load_config(UpConfig, file=tmp_path / "best.toml")


def test_the_prototypes_table_names_the_policy_s_own_moves(tmp_path: Path) -> None:
    report = run_report(tmp_path)  # shared-difference: compass moves
    assert "| N | NE | E | SE | S | SW | W | NW |" in markdown_report(report)
    report["config"]["formulation"] = "frame-difference"  # relative moves: no compass point among them
    text = markdown_report(report)
    assert "| toward | toward-left | left | away-left | away | away-right | right | toward-right |" in text
    assert "| N | NE |" not in text


def test_a_stopped_run_s_report_says_how_it_ended_and_how_to_continue(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    resume = f"ennc-ql up --resume {tmp_path}"
    report["interrupted"] = {"signal": "SIGTERM", "at_s": 215.4, "duration_s": 480.0, "learner": "killed"}
    report["interrupted"]["resume"] = resume
    report["final_coverage_mean"] = None
    summary = terminal_summary(report)
    assert summary.startswith("interrupted by SIGTERM at 215/480 s of training; the learner was killed")
    assert "result so far: policy version 37, not scored at the end (stopped); its last evaluation: 61.23 %" in summary
    assert f"  {resume}" in summary and "(265 s of training left)" in summary
    assert "**Interrupted by SIGTERM at 215/480 s of training" in markdown_report(report)


def test_after_a_slurm_job_the_next_commands_are_new_jobs_not_arguments_to_its_script(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    report["command"] = f"sbatch {tmp_path / 'job.sh'}"
    lines = [line for line, _ in next_commands(report)]
    assert not [line for line in lines if line.startswith("sbatch")]
    again = f"ennc-ql slurm train --config {tmp_path / 'up.toml'} --run-id NEW-ID --submit"
    assert again in lines and not [line for line in lines if "--duration" in line]


SAVED = {
    "version": 41,
    "at_s": 480.3,
    "margin": 1.0,
    "reason": "the last tables, the margin that scored best on 300 validation trials",
    "choice": {
        "validation_coverage": {"0": 76.62, "0.5": 77.85, "1": 78.13, "2": 77.76},
        "validation_spread": {"0": 1.13, "0.5": 1.074, "1": 1.064, "2": 1.053},
        "validation_trials": 300,
        "validation_seed": 1000,
    },
}
"""A run report's ``saved`` (``algorithm.selection.SavedPolicy.to_dict``)."""


def test_the_saved_policy_is_named_as_the_run_recorded_it(tmp_path: Path) -> None:
    text = write_run_report({**run_report(tmp_path), "saved": SAVED}, tmp_path)[0].read_text()
    assert "| **learned policy** | version 41, formulation shared-difference | **61.23** |" in text
    assert (
        "| saved policy | version 41 of 480 s, the last tables, the margin that scored best on 300 validation trials; "
        "law margin 1 (validation seed 1000, % observed at robots per covered target: 0 76.62 % at 1.130, 0.5 "
        "77.85 % at 1.074, 1 78.13 % at 1.064, 2 77.76 % at 1.053) |" in text
    )
    given = {**SAVED, "margin": 0.5, "choice": None, "reason": "the last tables, the margin given"}
    text = write_run_report({**run_report(tmp_path), "saved": given}, tmp_path)[0].read_text()
    assert "| saved policy | version 41 of 480 s, the last tables, the margin given; law margin 0.5 |" in text
    assert "saved policy" not in write_run_report(run_report(tmp_path), tmp_path)[0].read_text()


def test_the_result_leads_with_what_learning_added_over_its_base_law(tmp_path: Path) -> None:
    """A law action set's run is read against the law its move ``law`` follows, first, with its decisions off the
    law; a difference under two standard errors says so."""
    report = run_report(tmp_path)
    comparison = {**report["final_comparison"]}
    comparison["force-recall"] = {**comparison["a-cmommt"], "learned_minus": 0.31, "learned_minus_se": 0.21}
    comparison["learned"] = {
        **comparison["learned"],
        "off_law_pct": 12.5,
        "shared_decisions_pct": 8.0,
        "shared_off_law_pct": 2.25,
    }
    report = {**report, "final_comparison": comparison, "base_law": "force-recall"}
    lines = terminal_summary(report).splitlines()
    assert lines[0] == (
        "result: learned - force law + shared flags + memory (its base law): +0.31 ± 0.21 points, within noise "
        "(|difference| < 2 s.e.) (paired, 50 trials)"
    )
    assert lines[1] == (
        "decisions off the law: 12.5 %; where a teammate shared the robot's targets (8.0 % of the decisions): 2.2 %"
    )
    assert "learned - A-CMOMMT: -11.02 ± 0.50 points (paired, 50 trials)" in lines
    assert not [line for line in lines if "team table" in line]  # a one-table policy has none
    team = {"coverage": 61.5, "per_robot_minus": -0.27, "per_robot_minus_se": 0.08, "off_law_pct": 3.0}
    lines = terminal_summary({**report, "team_table": team}).splitlines()
    assert lines[2] == (
        "each robot on its own table (option 2, saved) - the rows merged into one team table: -0.27 ± 0.08 points "
        "(team table 61.50 %)"
    )
    text = write_run_report(report, tmp_path)[0].read_text()
    assert (
        "What learning added over its base law, force law + shared flags + memory: **+0.31 ± 0.21 points, within noise"
        in text
    )
    assert "Its robots left the law on 12.5 % of their decisions; where a teammate shared the robot's targets" in text


def test_the_learned_policy_s_decisions_off_law_are_given_when_counted(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    comparison = {**report["final_comparison"]}
    comparison["learned"] = {**comparison["learned"], "off_law_pct": 26.022}
    text = write_run_report({**report, "final_comparison": comparison}, tmp_path)[0].read_text()
    assert "| decisions off law | 26.0 % of the learned robots' decisions on the final trials |" in text
    assert "decisions off law" not in write_run_report(report, tmp_path)[0].read_text()


def test_without_a_display_the_recording_is_served_to_a_browser_on_loopback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    commands = dict(next_commands(run_report(tmp_path)))
    serve = f"rerun --serve-web --bind 127.0.0.1 {tmp_path / 'recording.rrd'}"
    assert serve in commands and f"rerun {tmp_path / 'recording.rrd'}" not in commands
    assert (
        "http://127.0.0.1:9090" in commands[serve]
        and "ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876" in (commands[serve])
    )


def test_a_resumed_run_keeps_its_interruptions_in_the_report_and_its_resumes_on_the_curve(tmp_path: Path) -> None:
    first = {
        "signal": "SIGINT",
        "at_s": 27.4,
        "duration_s": 60.0,
        "learner": "finished",
        "resume": "ennc-ql up --resume x",
    }
    report = {
        **run_report(tmp_path),
        "interruptions": [first],
        "resumes": [{"at_s": 27.4, "policy_version": 9, "wall_time": 0.0, "startup_s": 4.0}],
        "saved": {**SAVED, "margin": 0.5},
    }
    text = write_run_report(report, tmp_path)[0].read_text()
    assert "| interruptions | SIGINT at 27/60 s, then resumed |" in text
    ax = learning_curve_figure(report).axes[0]
    labels = {line.get_label(): line for line in ax.get_lines()}
    assert labels["resumed from the checkpoint"].get_xdata()[0] == 27.4
    assert "saved: the last policy, margin 0.5: 61.23 % (50 trials)" in labels
    # Stopped again after the resume: both stops, the last one not resumed (yet).
    second = {**first, "signal": "SIGTERM", "at_s": 50.0}
    text = write_run_report({**report, "interruptions": [first, second], "interrupted": second}, tmp_path)[0]
    assert "| interruptions | SIGINT at 27/60 s, then resumed; SIGTERM at 50/60 s |" in text.read_text()


def test_the_launchers_figures_reach_report_json_typed_and_read_back_the_same(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """The learner's report and the launcher's summary become one typed RunReport on their way to report.json,
    report.md and the terminal: what is printed is what is written, and it reads back to the same records."""
    learner = LearnerReport.from_dict({**run_report(tmp_path), "policy_file": None})
    run = ProcessRun(
        "tcp/127.0.0.1:7447",
        started=0.0,
        restarts={"learner": 1, "actor-0": 2},
        events=[Restart("learner", -9, ran_s=30.0, noticed_at=100.0, delay_s=1.0)],
        actors_sent={"actor-0": {"incarnations": 3, "reported": 3, "tuples_sent": 10, "tuples_acked": 10}},
        first_policy_s=12.5,
        versions=[1, 2, 5],
    )
    stopped = Interruption("SIGTERM", 215.4, 480.0, "finished", "ennc-ql up --resume x", signals=1)
    recording = RecordingFigures(str(tmp_path / "recording.rrd"), 10, ("x",), ("learner/coverage",), 5)
    summary = RunSummary(
        tmp_path, "ennc-ql up --config x", UpConfig(), True, 500.0, recording, run=run, interrupted=stopped
    )
    written.emit_run_report(learner, summary, as_json=True)
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert json.loads(capsys.readouterr().out) == on_disk
    back = RunReport.from_dict(on_disk)
    assert back.learner == learner and back.launch == summary.figures(learner)
    assert back.report_md == str(tmp_path / "report.md") and back.policy_figure is None
    assert on_disk["learner_restarts"] == [{"status": -9, "ran_s": 30.0, "delay_s": 1.0, "back_in_s": None}]
    assert on_disk["actor_restarts"] == {"actor-0": 2} and on_disk["interruptions"] == [on_disk["interrupted"]]
    assert on_disk["policy_versions"] == {"seen": 3, "first": 1, "last": 5, "increasing": True}
    assert on_disk["config"] == {
        "actors": 2,
        "duration": UpConfig().duration,
        "seed": 0,
        "formulation": DEFAULT_FORMULATION,
        "serial": False,
        "secure": True,
    }
    assert "**Interrupted by SIGTERM at 215/480 s of training" in (tmp_path / "report.md").read_text()
