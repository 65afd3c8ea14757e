"""Recording a test trial for replay: one arena logged at every step, with its coverage."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from monitor import Sink, open_monitor, paths, summarize_recording
from monitor.trial import record_trial, trial_hook
from sim import HAND_MADE, evaluate, scenario
from tests.monitor.rrd import layout, rows

STEPS = 30


def logged_coverage(path: Path) -> list[tuple[int, float]]:
    return [(t, values[0]) for t, values in rows(path, paths.EVAL_COVERAGE, "Scalars:scalars", paths.SIM_STEP)]


def test_record_trial_logs_the_arena_at_every_step(tmp_path: Path) -> None:
    cfg, controller = scenario(), HAND_MADE["a-cmommt"]
    path = tmp_path / "trial.rrd"
    with open_monitor(Sink("save", str(path)), process="eval", recording_id="trial") as monitor:
        monitor.send_blueprint(eval_trial=True)
        score = record_trial(cfg, controller, monitor, seed=3, steps=STEPS)
    assert score == pytest.approx(evaluate(cfg, controller, trials=1, steps=STEPS, seed=3).coverage_mean)
    summary = summarize_recording(path)
    for part in ("robots", "targets", "sensing"):
        assert summary["rows_per_entity"][f"{paths.EVAL_ARENA}/{part}"] == STEPS
    assert f"{paths.EVAL_ARENA}/boundary" in summary["entity_paths"]
    coverage = logged_coverage(path)
    assert [t for t, _ in coverage] == list(range(1, STEPS + 1))
    assert np.mean([v for _, v in coverage]) == pytest.approx(score)
    replay = layout(path)
    views = {view.name: (view.kind, view.origin) for view in replay.views}
    # The arena is seen from its parent, so that the arena root's north-up mirror applies.
    assert views == {"test trial": ("2D", paths.EVAL), "key": ("2D", paths.KEY), "coverage (%)": ("TimeSeries", "/")}
    assert replay.time_panel["TimePanelBlueprint:timeline"] == paths.SIM_STEP


def test_trial_hook_records_the_chosen_trial_of_an_evaluation(tmp_path: Path) -> None:
    cfg, controller = scenario(), HAND_MADE["random"]
    path = tmp_path / "eval.rrd"
    with open_monitor(Sink("save", str(path)), process="eval", recording_id="eval") as monitor:
        result = evaluate(cfg, controller, trials=3, steps=STEPS, seed=0, on_step=trial_hook(monitor, cfg, arena=2))
    coverage = logged_coverage(path)
    assert len(coverage) == STEPS
    assert np.mean([v for _, v in coverage]) == pytest.approx(result.coverage_per_trial[2])
