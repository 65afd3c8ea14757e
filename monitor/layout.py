"""The default viewer layout. Imports Rerun: only :mod:`monitor.rerun_monitor` uses it.

A researcher opening a run should see the learning curve at once, as TensorBoard and W&B show the main scalar first,
large, over the whole history: so the viewer opens at the end of the data (following a live run), every time series
spans the whole run on the ``train_time`` timeline, and the test coverage has a panel of its own, first and largest,
with the hand-made controllers' levels and the final figure. Training-trial figures come next, then the arenas and
the prototypes (a rose of the action set's moves: for the compass, north up), then the system figures. Colours come
from :mod:`monitor.style`, one per actor and per statistic in every panel; the logged data only name their series.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import rerun as rr
import rerun.blueprint as rrb
from rerun.blueprint.api import VisualizerLike
from rerun.blueprint.components import Corner2D
from rerun.encodings import EntityPathLike

from monitor import paths, style
from monitor.geometry import PROTOTYPE_REACH
from sim.actions import ActionSet
from sim.formulation import default_formulation


def rose(actions: ActionSet) -> tuple[int | None, ...]:
    """Action of each cell of the 3x3 rose, row by row from the top left, the key in the middle: each action in the
    cell its direction points to (compass: NW N NE / W key E / SW S SE; relative: the move ``toward`` the nearest
    target on the right, as the target frame's prototypes are drawn)."""
    cells: list[int | None] = [None] * 9
    for k, (dx, dy) in enumerate(actions.directions):
        cells[3 * (1 - round(float(dy))) + round(float(dx)) + 1] = k
    return tuple(cells)


ARENA_MARGIN = 1.05
"""Half-width of an arena view in arena radii."""

KEY_BOUNDS = rrb.VisualBounds2D(x_range=(0.0, 10.0), y_range=(0.0, 8.0))
"""The key's own coordinates (see :mod:`monitor.drawings`): not an arena, so +y simply runs down the rows."""

TITLE_MAX = 24
"""Longest view title: titles stay whole in a panel a few hundred pixels wide."""

WHOLE_RUN = rrb.TimeAxis(
    view_range=rr.TimeRange(start=rrb.TimeRangeBoundary.infinite(), end=rrb.TimeRangeBoundary.infinite())
)
"""The x-range of every time series: the whole run, however long, wherever the time cursor is."""

Styled = Mapping[str, rr.SeriesLines | rr.SeriesPoints]


def _lines(color: style.Rgb, width: float = style.WIDTH) -> rr.SeriesLines:
    return rr.SeriesLines.from_fields(colors=[color], widths=[width])


def _series(
    name: str, styled: Styled, *, legend: Corner2D | None = None, y_range: tuple[float, float] | None = None
) -> rrb.TimeSeriesView:
    """A time series of the ``styled`` paths over the whole run; ``legend`` is the corner the data leave free
    (None: no legend; the title names the one series, or other panels' legends name the colours)."""
    overrides: dict[EntityPathLike, VisualizerLike] = {path: series for path, series in styled.items()}
    return rrb.TimeSeriesView(
        name=name,
        origin="/",
        contents=list(styled),
        axis_x=WHOLE_RUN,
        axis_y=None if y_range is None else rrb.ScalarAxis(range=y_range),
        plot_legend=rrb.PlotLegend(visible=False) if legend is None else rrb.PlotLegend(legend),
        overrides=overrides,
    )


def _per_actor(actor_ids: Sequence[str], metric: str) -> dict[str, rr.SeriesLines]:
    return {paths.actor(a, metric): _lines(style.actor_color(a)) for a in actor_ids}


def _learning(actor_ids: Sequence[str]) -> rrb.Container:
    """The learning curve, large, beside the training trials' coverage and reward."""
    curve: dict[str, rr.SeriesLines | rr.SeriesPoints] = {
        paths.LEARNER_COVERAGE_EVAL: _lines(style.LEARNED, style.MAIN_WIDTH),
        paths.LEARNER_COVERAGE_FINAL: rr.SeriesPoints.from_fields(
            colors=[style.LEARNED], markers=["diamond"], marker_sizes=[style.MARKER_SIZE]
        ),
    }
    for controller, (_, color) in style.REFERENCES.items():
        curve[paths.reference(controller)] = _lines(color, style.REFERENCE_WIDTH)
    # Coverage runs 0-100 %: the levels (17-75 %) and the curve leave the top free; the left, since the curve's right
    # end and the final figure's marker sit at the top of the data, and a legend there would hide them.
    test = _series("test coverage (%)", curve, legend=Corner2D.LeftTop, y_range=(0.0, 100.0))
    # Both training figures rise from the left, leaving the bottom right free.
    training = rrb.Vertical(
        _series(
            "training coverage (%)",
            _per_actor(actor_ids, paths.ACTOR_COVERAGE),
            legend=Corner2D.RightBottom,
            y_range=(0.0, 100.0),
        ),
        _series("mean trial reward", _per_actor(actor_ids, paths.ACTOR_REWARD), legend=Corner2D.RightBottom),
        rrb.TextDocumentView(name="spread over targets", origin=paths.LEARNER_COOPERATION),
        name="training trials",
    )
    return rrb.Horizontal(test, training, column_shares=[3, 2], name="learning")


def _system(actor_ids: Sequence[str]) -> rrb.Container:
    """The system's figures, one short title each, the learner grey and each actor its colour.

    Legends only where the data leave a corner free; lag and memory have none, and their colours are the ones the
    throughput and version legends name (the viewer also names each series on hover).
    """
    learner = _lines(style.LEARNER)
    lag = {paths.learner_lag(a): _lines(style.actor_color(a)) for a in actor_ids}
    q = {f"{paths.LEARNER_Q}/{stat}": _lines(color) for stat, color in style.Q_STATS.items()}
    views = [
        # Throughput falls from its start-up peak: the top right stays free.
        _series(
            "tuples/s",
            {paths.LEARNER_TUPLES_PER_S: learner, **_per_actor(actor_ids, paths.ACTOR_TUPLES_PER_S)},
            legend=Corner2D.RightTop,
        ),
        # Versions only grow: the top left stays free.
        _series(
            "policy version",
            {paths.LEARNER_POLICY_VERSION: learner, **_per_actor(actor_ids, paths.ACTOR_POLICY_VERSION)},
            legend=Corner2D.LeftTop,
        ),
        _series("policy lag (versions)", lag),
        # max >= mean >= min: the lines read top-down in the title's order.
        _series("Q: max, mean, min", q),
        _series("tuples stored", {paths.LEARNER_STORE_SIZE: learner}),
        _series("live actors", {paths.LEARNER_LIVE_ACTORS: learner}),
        _series("rejected messages", {paths.LEARNER_REJECTED: learner}),
        _series("memory (RSS, MB)", {paths.LEARNER_RSS: learner, **_per_actor(actor_ids, paths.ACTOR_RSS)}),
    ]
    return rrb.Grid(*views, grid_columns=2, name="system")


def _square(length: float | None, factor: float) -> rrb.VisualBounds2D | None:
    """Bounds of ``factor * length`` around the origin; None (fitted to the data) when the length is unknown."""
    if length is None:
        return None
    half = factor * length
    return rrb.VisualBounds2D(x_range=(-half, half), y_range=(-half, half))


def _parent(path: str) -> str:
    return path.rsplit("/", 1)[0]


def _drawing(name: str, root: str, bounds: rrb.VisualBounds2D | None) -> rrb.Spatial2DView:
    """A 2-D view of the drawing under ``root``, seen from its parent so that the root's north-up flip applies."""
    return rrb.Spatial2DView(name=name, origin=_parent(root), contents=f"{root}/**", visual_bounds=bounds)


def _key_view() -> rrb.Spatial2DView:
    return rrb.Spatial2DView(name="key", origin=paths.KEY, contents=f"{paths.KEY}/**", visual_bounds=KEY_BOUNDS)


def _rose(sensing_range: float | None, actions: ActionSet) -> rrb.Container:
    """The prototype views as a rose around the key, one shared fixed range (None: fitted to the data)."""
    bounds = _square(sensing_range, PROTOTYPE_REACH)
    moves = actions.moves
    cells = [_key_view() if k is None else _drawing(moves[k], paths.prototypes_of(k), bounds) for k in rose(actions)]
    return rrb.Grid(*cells, grid_columns=3, name="prototypes by Q")


def _below(
    actor_ids: Sequence[str], arena_radius: float | None, sensing_range: float | None, actions: ActionSet
) -> rrb.Container:
    """Arenas, the rose of the moves and system side by side: each gets the row's height, which keeps the 2-D views
    about square in a landscape window."""
    columns = max(1, math.ceil(len(actor_ids) / 2))  # two arenas stacked per column of a ~300-pixel width
    bounds = _square(arena_radius, ARENA_MARGIN)
    arenas = rrb.Grid(
        *[_drawing(f"{a} arena", paths.actor_arena(a), bounds) for a in actor_ids], grid_columns=columns, name="arenas"
    )
    return rrb.Horizontal(arenas, _rose(sensing_range, actions), _system(actor_ids), column_shares=[columns, 2, 3])


def default_blueprint(
    actor_ids: Sequence[str],
    *,
    eval_trial: bool = False,
    arena_radius: float | None = None,
    sensing_range: float | None = None,
    actions: ActionSet | None = None,
) -> rrb.Blueprint:
    """The training layout (learning curves, arenas and prototypes, system), or for ``eval_trial`` (``ennc-ql eval``
    recording a trial) the trial, its coverage and the key. ``actions``: the moves the prototype views are named and
    laid out by (None: the run's default formulation's).

    View contents list every path explicitly: Rerun 0.41 query expressions only allow ``/**`` as a wildcard and
    visualizer overrides (the colours) take exact paths, so a per-actor series needs its actor id here, and an actor
    that joins later appears once the blueprint is re-sent.
    """
    if eval_trial:
        trial = _drawing("test trial", paths.EVAL_ARENA, _square(arena_radius, ARENA_MARGIN))
        coverage = _series("coverage (%)", {paths.EVAL_COVERAGE: _lines(style.LEARNED)}, y_range=(0.0, 100.0))
        root = rrb.Vertical(rrb.Horizontal(trial, _key_view(), column_shares=[3, 1]), coverage, row_shares=[3, 1])
        # A replayed trial plays from its first step.
        time_panel = rrb.TimePanel(timeline=paths.SIM_STEP, state="collapsed")
    else:
        root = rrb.Vertical(
            _learning(actor_ids),
            _below(actor_ids, arena_radius, sensing_range, actions or default_formulation().actions),
            row_shares=[1, 1],
        )
        # Opening at the end (and following a live run) shows the whole curve and the latest arena and policy.
        time_panel = rrb.TimePanel(timeline=paths.TRAIN_TIME, play_state="following", state="collapsed")
    return rrb.Blueprint(
        root,
        time_panel,
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        auto_views=False,
    )
