"""The viewer layout the learner sends, read back from its recording: what a new user sees without configuring
anything (the whole run on every curve, the learning curve first with its reference levels, one colour per actor,
north-up compass rose of prototype views)."""

from __future__ import annotations

from pathlib import Path

import pytest
import rerun.blueprint as rrb

from algorithm.selection import DEVELOPMENT_SEED
from learner.config import LearnerConfig
from learner.service import LearnerService
from monitor import Sink, open_monitor, paths, style
from monitor.layout import TITLE_MAX, rose
from protocol import InMemoryBus, InMemoryTransport
from sim import COMPASS, CONTROLLERS, evaluate, scenario
from sim.actions import ACTION_SETS
from sim.controllers import COMPASS_NAMES
from tests.monitor.rrd import Layout, View, layout, rows

ACTORS = ("actor-0", "actor-1", "actor-2")
CONFIG = LearnerConfig(formulation="paper", eval_trials=2, eval_steps=40)
"""The paper's formulation: its compass moves lay the prototype views out as a north-up rose."""


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The learner's part of a recording: its start-up (reference levels), actors joining, one status publish."""
    run_dir = tmp_path_factory.mktemp("run")
    path = paths.part_file(run_dir, "learner")
    with (
        open_monitor(Sink("save", str(path)), process="learner", recording_id="layout") as monitor,
        InMemoryTransport(InMemoryBus()) as transport,
    ):
        service = LearnerService(transport, CONFIG, run_dir, monitor=monitor)
        service.watch.started(CONFIG.resolved, service.evaluator.references)
        for actor in ACTORS:
            service.members.on_join(transport.keys.alive("actor", actor))
        service._publish_status()
    return path


@pytest.fixture(scope="module")
def sent(recording: Path) -> Layout:
    return layout(recording)


def view(sent: Layout, name: str) -> View:
    (found,) = [v for v in sent.views if v.name == name]
    return found


def test_every_time_series_spans_the_whole_run(sent: Layout) -> None:
    curves = [v for v in sent.views if v.kind == "TimeSeries"]
    assert len(curves) >= 10
    for curve in curves:
        assert curve.properties["TimeAxis"]["view_range"] == {"start": "Infinite", "end": "Infinite"}, curve.name


def test_the_viewer_opens_at_the_end_on_training_time(sent: Layout) -> None:
    assert sent.time_panel["TimePanelBlueprint:timeline"] == paths.TRAIN_TIME
    assert sent.time_panel["TimePanelBlueprint:play_state"] == rrb.components.PlayState.Following.value


def test_the_learning_curve_comes_first_with_its_reference_levels(sent: Layout) -> None:
    first = sent.views[0]
    assert (first.name, first.kind) == ("test coverage (%)", "TimeSeries")
    references = [paths.reference(name) for name in style.REFERENCES]
    assert first.contents == [paths.LEARNER_COVERAGE_EVAL, paths.LEARNER_COVERAGE_FINAL, *references]
    assert first.overrides[paths.LEARNER_COVERAGE_FINAL]["VisualizerInstruction:visualizer_type"] == "SeriesPoints"
    for series in (paths.LEARNER_COVERAGE_EVAL, *references):
        assert first.overrides[series]["VisualizerInstruction:visualizer_type"] == "SeriesLines"
    assert first.properties["ScalarAxis"]["range"] == [0.0, 100.0]
    # Training trials (a different protocol) have a panel of their own, next to it.
    assert sent.containers["learning"] == ["test coverage (%)", "training trials"]
    assert sent.containers["training trials"] == ["training coverage (%)", "mean trial reward", "spread over targets"]


def test_reference_levels_are_the_hand_made_controllers_on_the_curve_s_trials(recording: Path) -> None:
    cfg = scenario(CONFIG.scenario)
    for name, controller in CONTROLLERS.items():
        expected = evaluate(cfg, controller, CONFIG.eval_trials, CONFIG.eval_steps, seed=DEVELOPMENT_SEED).coverage_mean
        ((_, level),) = rows(recording, paths.reference(name), "Scalars:scalars", paths.TRAIN_TIME)
        assert level == [pytest.approx(expected)]
    assert set(style.REFERENCES) == set(CONTROLLERS)  # each level has its legend name and colour


def test_titles_are_unique_and_short(sent: Layout) -> None:
    names = [v.name for v in sent.views]
    assert len(names) == len(set(names))
    assert max(len(name) for name in names) <= TITLE_MAX


def test_system_figures_have_a_section_of_their_own(sent: Layout) -> None:
    system = sent.containers["system"]
    for figure in ("tuples/s", "policy version", "policy lag (versions)", "tuples stored", "live actors"):
        assert figure in system
    assert {"rejected messages", "memory (RSS, MB)"} <= set(system)


def series_colors(sent: Layout) -> dict[str, set[int]]:
    """Entity path -> the colours the views' overrides give it."""
    colors: dict[str, set[int]] = {}
    for v in sent.views:
        for path, fields in v.overrides.items():
            color = fields.get("SeriesLines:colors", fields.get("SeriesPoints:colors"))
            colors.setdefault(path, set()).add(color)
    return colors


def test_every_actor_has_one_colour_everywhere(sent: Layout) -> None:
    colors = series_colors(sent)
    by_actor: dict[str, set[int]] = {}
    for path, used in colors.items():
        for actor in ACTORS:
            if path.startswith(f"{paths.ACTORS}/{actor}/") or path == paths.learner_lag(actor):
                by_actor.setdefault(actor, set()).update(used)
    assert set(by_actor) == set(ACTORS)
    assert all(len(used) == 1 for used in by_actor.values()), by_actor
    actor_colors = [next(iter(used)) for used in by_actor.values()]
    assert len(set(actor_colors)) == len(ACTORS)  # distinct actors, distinct colours
    assert colors[paths.LEARNER_TUPLES_PER_S].isdisjoint(actor_colors)  # and never the learner's
    # Each Q statistic its own colour.
    assert len(set().union(*(colors[f"{paths.LEARNER_Q}/{stat}"] for stat in paths.Q_STATS))) == len(paths.Q_STATS)


def test_prototype_views_form_a_north_up_compass_rose(sent: Layout) -> None:
    assert sent.containers["prototypes by Q"] == ["NW", "N", "NE", "W", "key", "E", "SW", "S", "SE"]
    prototypes = [v for v in sent.views if v.origin == paths.LEARNER_PROTOTYPES]
    assert sorted(v.name for v in prototypes) == sorted(COMPASS_NAMES)
    reach = 1.2 * scenario(CONFIG.scenario).sensing_range
    for v in prototypes:
        action = COMPASS_NAMES.index(v.name)
        assert v.contents == [f"{paths.prototypes_of(action)}/**"]
        assert v.properties["VisualBounds2D"]["range"] == {"x_range": [-reach, reach], "y_range": [-reach, reach]}
    # The rose reads like a map: N is the move up (+y), E the move right (+x).
    assert COMPASS[COMPASS_NAMES.index("N")].tolist() == pytest.approx([0.0, 1.0])
    assert COMPASS[COMPASS_NAMES.index("E")].tolist() == pytest.approx([1.0, 0.0])


def test_the_rose_places_every_move_where_it_points() -> None:
    # Compass: NW N NE / W key E / SW S SE. Relative: "toward" the nearest target points along the target frame's
    # +x, drawn to the right, and "left" (towards the furthest target's side, +y) at the top.
    assert rose(ACTION_SETS["compass"]) == (7, 0, 1, 6, None, 2, 5, 4, 3)
    assert rose(ACTION_SETS["relative"]) == (3, 2, 1, 4, None, 0, 5, 6, 7)
    assert [ACTION_SETS["relative"].moves[k] for k in (2, 0, 4)] == ["left", "toward", "away"]


def test_every_actor_has_an_arena_seen_from_above_its_root(sent: Layout) -> None:
    arenas = {v.name: (v.origin, v.contents) for v in sent.views if v.name.endswith(" arena")}
    assert arenas == {
        f"{actor} arena": (f"{paths.ACTORS}/{actor}", [f"{paths.actor_arena(actor)}/**"]) for actor in ACTORS
    }


def test_the_spread_over_the_targets_reaches_the_viewer_as_one_table_per_evaluation(tmp_path: Path) -> None:
    path = tmp_path / "cooperation.rrd"
    spread = {"only_shared_pct": 12.5, "none_in_view_pct": 30.25, "robots_per_covered_target": 1.125}
    table = {
        "learned": {"coverage": 72.5, **spread},
        "a-cmommt": {"coverage": 78.0, **spread, "learned_minus": -5.5, "learned_minus_se": 0.5},
        "a-cmommt-oracle": {"coverage": 74.0, **spread, "learned_minus": -1.5, "learned_minus_se": 0.5},
    }
    with open_monitor(Sink("save", str(path)), process="learner", recording_id="spread") as monitor:
        monitor.cooperation(table, trials=200, policy_version=3, learner_step=1)
        monitor.cooperation({"learned": table["learned"]}, trials=10, policy_version=4, learner_step=2)
    ((_, first), (_, second)) = rows(path, paths.LEARNER_COOPERATION, "TextDocument:text", paths.TRAIN_TIME)
    lines = first[0].splitlines()
    assert lines[0].startswith("Per robot-step on 200 test trials")
    assert lines[4:] == [
        "| learned policy | 72.50 | 12.5 | 30.2 | 1.125 |",
        "| A-CMOMMT | 78.00 (learned -5.50) | 12.5 | 30.2 | 1.125 |",
        "| A-CMOMMT oracle (true positions) | 74.00 (learned -1.50) | 12.5 | 30.2 | 1.125 |",
    ]
    assert second[0].startswith("Per robot-step on 10 test trials") and len(second[0].splitlines()) == 5
