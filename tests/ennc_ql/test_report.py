"""Run reports: ``report.md`` carries the run's figures, ``learning_curve.png`` is a real chart of the curve."""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.image import imread

from actors.config import ActorConfig
from ennc_ql.cli import build_parser
from ennc_ql.cluster import UP_PRESETS, UpConfig, child_configs, write_configs
from ennc_ql.config import ConfigError, load_config
from ennc_ql.report import (
    FINAL_REFERENCE,
    HAND_MADE_COVERAGE,
    learning_curve_figure,
    results_table,
    write_run_report,
)
from learner.config import LearnerConfig
from sim import HAND_MADE, evaluate, scenario
from sim.features import DEFAULT_FORMULATION, FORMULATIONS

CURVE_BLUE = (0x3B / 255, 0x7D / 255, 0xD8 / 255)


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
        "policy_file": str(run_dir / "policy.npz"),
        "checkpoint": str(run_dir / "checkpoint.npz"),
        "seconds": 480.31,
        "run_id": "20260101-120000",
        "run_dir": str(run_dir),
        "command": "ennc-ql up --actors 2 --duration 480",
        "config": {"actors": 2, "duration": 480.0, "arenas": 500, "seed": 0},
        "wall_seconds": 512.4,
    }


def blue_pixels(image: np.ndarray) -> int:
    """Pixels of the learned curve's colour (its filled markers; the thin reference lines blend with white)."""
    return int((np.abs(image[..., :3] - np.asarray(CURVE_BLUE)) < 0.02).all(axis=-1).sum())


def test_markdown_report_carries_the_figures(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    markdown_path, png_path = write_run_report(report, tmp_path)
    assert (markdown_path, png_path) == (tmp_path / "report.md", tmp_path / "learning_curve.png")
    text = markdown_path.read_text()
    assert text.startswith("# ennc-ql run 20260101-120000\n")
    assert "ennc-ql up --actors 2 --duration 480" in text
    assert "| duration | 480 |" in text and "| arenas | 500 |" in text
    assert "| tuples received | 2,457,600 |" in text
    assert "| final coverage | 61.23 % |" in text
    for row in ("| 95 | 48.50 |", "| 216 | 57.12 |", "| 338 | 60.40 |", "| 480 | 61.23 |"):
        assert row in text
    assert "| actor-0 | 1,228,800 | 50.0 % |" in text
    assert "5,120 tuples/s" in text and "2,057,600 overwritten" in text
    assert "| duplicate batches | 3 |" in text and "| sequence gaps | 1 |" in text
    assert "| rejected by type | ExperienceBatch: 2 |" in text
    assert "| policy lag per actor (versions) | actor-0: 0, actor-1: 1 |" in text
    assert "| 201 | 188 | 247 | 230 | 196 | 215 | 260 | 221 |" in text and "mean 219.8" in text
    assert f"`{tmp_path / 'policy.npz'}`" in text
    assert "](learning_curve.png)" in text
    assert "A-CMOMMT 68.26 %" in text and "on the final figure's 50 trials A-CMOMMT scores 73.07 %" in text


def test_learning_curve_plots_the_curve_and_the_reference_levels(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    ax = learning_curve_figure(report).axes[0]
    lines = {line.get_label(): line for line in ax.get_lines()}
    np.testing.assert_allclose(np.asarray(lines["learned policy"].get_xydata()), report["coverage_curve"])
    assert set(lines) == {
        "learned policy",
        "random, hand-made (16.60 %)",
        "local, hand-made (56.92 %)",
        "force-6d-shared, hand-made (69.09 %)",
        "A-CMOMMT, hand-made (68.26 %)",
        "A-CMOMMT oracle, hand-made (72.14 %)",
        "final policy (50 test trials)",
        "A-CMOMMT, hand-made (50 test trials, 73.07 %)",
    }
    assert np.asarray(lines["A-CMOMMT, hand-made (68.26 %)"].get_ydata()).tolist() == [68.26, 68.26]
    # The final figure is its own point, at the end of training.
    assert lines["final policy (50 test trials)"].get_xydata().tolist() == [[report["seconds"], 61.234]]
    assert lines["A-CMOMMT, hand-made (50 test trials, 73.07 %)"].get_xydata().tolist() == [[report["seconds"], 73.07]]
    assert ax.get_xlim()[1] >= 480.3 and ax.get_ylim() == (0, 100)


def test_the_reference_levels_are_what_eval_measures() -> None:
    names = {
        "random": "random",
        "local": "local",
        "force-6d-shared": "force-6d-shared",
        "A-CMOMMT": "a-cmommt",
        "A-CMOMMT oracle": "a-cmommt-oracle",
    }
    for label, level in HAND_MADE_COVERAGE.items():
        assert evaluate(scenario(), HAND_MADE[names[label]], 10, 1000, seed=0).coverage_mean == pytest.approx(
            level, abs=0.005
        )
    name, trials, level = FINAL_REFERENCE
    assert evaluate(scenario(), HAND_MADE[names[name]], trials, 1000, seed=0).coverage_mean == pytest.approx(
        level, abs=0.005
    )


def test_learning_curve_png_is_an_image_of_the_chart(tmp_path: Path) -> None:
    _, png_path = write_run_report(run_report(tmp_path), tmp_path)
    image = imread(png_path)
    assert image.shape == (495, 880, 4)  # 8 x 4.5 inches at 110 dpi
    assert blue_pixels(image) > 200  # the learned policy's markers and line


def test_a_run_without_a_policy_still_gets_a_report(tmp_path: Path) -> None:
    report = run_report(tmp_path)
    report.update(coverage_curve=[], final_coverage_mean=None, prototypes_per_action=[], policy_file=None)
    markdown_path, png_path = write_run_report(report, tmp_path)
    text = markdown_path.read_text()
    assert "| final coverage | – |" in text and "No evaluation: no policy was learned" in text
    assert "Prototypes per action" not in text
    assert [line.get_label() for line in learning_curve_figure(report).axes[0].get_lines()] == [
        f"{name}, hand-made ({level:.2f} %)" for name, level in HAND_MADE_COVERAGE.items()
    ]
    image = imread(png_path)
    assert image.shape == (495, 880, 4) and blue_pixels(image) == 0


def test_the_learner_report_alone_is_enough(tmp_path: Path) -> None:
    """The launcher's keys are optional: a learner run on its own can be reported too."""
    report = run_report(tmp_path)
    for key in ("run_id", "command", "config", "wall_seconds"):
        del report[key]
    text = write_run_report(report, tmp_path)[0].read_text()
    assert text.startswith(f"# ennc-ql run {tmp_path.name}\n")
    assert "## Configuration" not in text and "| tuples received | 2,457,600 |" in text


def test_results_table_lists_the_figures(tmp_path: Path) -> None:
    lines = results_table(run_report(tmp_path)).splitlines()
    assert lines[0].split() == ["run", "folder", str(tmp_path)]
    assert "coverage curve         95s: 48.5%, 216s: 57.1%, 338s: 60.4%, 480s: 61.2%" in lines
    assert "duplicates / gaps      3 / 1" in lines


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
    assert learner.resolved == chosen and {a.resolved.featurizer for a in actors} == {chosen.featurizer}
    assert {(a.resolved.reward, a.resolved.actions) for a in actors} == {(chosen.reward, chosen.actions)}
    toml = tomllib.loads((tmp_path / "up.toml").read_text())
    assert toml["formulation"] == toml["learner"]["formulation"] == toml["actor"]["formulation"] == DEFAULT_FORMULATION
    assert not {"featurizer", "reward", "act_every"} & (set(toml["learner"]) | set(toml["actor"]))
    paper = load_config(UpConfig, args=build_parser().parse_args(["up", "--formulation", "paper"]), defaults=UP_PRESETS)
    learner, actors = child_configs(paper)
    assert {p.formulation for p in (paper.learner, paper.actor, learner, *actors)} == {"paper"}
    assert {(p.resolved.featurizer, p.resolved.reward) for p in (learner, *actors)} == {("collab6d", "eq2")}
    assert learner.resolved.act_every is None
    (tmp_path / "mixed.toml").write_text('formulation = "paper"\n[learner]\nreward = "difference"\n')
    with pytest.raises(ConfigError, match=r"learner.reward: up gives every process the formulation it names"):
        load_config(UpConfig, file=tmp_path / "mixed.toml")
    with pytest.raises(ConfigError, match="formulation: unknown 'best'"):
        load_config(UpConfig, args=build_parser().parse_args(["up", "--formulation", "best"]), defaults=UP_PRESETS)
