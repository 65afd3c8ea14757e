"""The default viewer layout. Imports Rerun: only :mod:`monitor.rerun_monitor` uses it."""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from monitor import paths


def _series(name: str, contents: list[str]) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(name=name, origin="/", contents=contents)


def default_blueprint(actor_ids: Sequence[str], n_actions: int, *, eval_trial: bool = False) -> rrb.Blueprint:
    """Arena views and prototypes (and a recorded trial) on top, the time series below.

    Without actors or actions (``ennc-ql eval`` recording a trial) only the trial and its coverage are laid out.

    View contents list every path explicitly: Rerun 0.41 query expressions only allow ``/**`` as a wildcard, so a
    per-actor series needs its actor id here, and an actor that joins later appears once the blueprint is re-sent.
    """
    spatial: list[rrb.Container | rrb.View] = []
    if actor_ids:
        arenas = [rrb.Spatial2DView(name=f"{a} arena", origin=paths.actor_arena(a)) for a in actor_ids]
        spatial.append(rrb.Grid(*arenas, name="arenas"))
    if n_actions > 0:
        panels = [rrb.Spatial2DView(name=f"action {k}", origin=paths.prototypes_of(k)) for k in range(n_actions)]
        spatial.append(rrb.Grid(*panels, name="prototypes by Q"))
    if eval_trial:
        spatial.append(rrb.Spatial2DView(name="test trial", origin=paths.EVAL_ARENA))

    def per_actor(metric: str) -> list[str]:
        return [paths.actor(a, metric) for a in actor_ids]

    coverage = [paths.LEARNER_COVERAGE_EVAL, *per_actor(paths.ACTOR_COVERAGE)]
    if eval_trial:
        coverage.append(paths.EVAL_COVERAGE)
    series = [_series("coverage (%)", coverage)]
    training = bool(actor_ids) or n_actions > 0
    if training:
        series += [
            _series("mean trial reward", per_actor(paths.ACTOR_REWARD)),
            _series("tuples/s", [paths.LEARNER_TUPLES_PER_S, *per_actor(paths.ACTOR_TUPLES_PER_S)]),
            _series("policy version", [paths.LEARNER_POLICY_VERSION, *per_actor(paths.ACTOR_POLICY_VERSION)]),
            _series("policy lag (versions)", [f"{paths.LEARNER_LAG}/**"]),
            _series("Q values", [f"{paths.LEARNER_Q}/**"]),
            _series("store size", [paths.LEARNER_STORE_SIZE]),
            _series("live actors, rejected messages", [paths.LEARNER_LIVE_ACTORS, paths.LEARNER_REJECTED]),
        ]
    curves = rrb.Grid(*series, name="curves")
    root = rrb.Vertical(rrb.Horizontal(*spatial), curves, row_shares=[3, 2]) if spatial else curves
    # Only wall time is common to every process of a training run; a replayed trial steps through sim_step.
    timeline = paths.WALL_TIME if training else paths.SIM_STEP
    return rrb.Blueprint(root, rrb.TimePanel(timeline=timeline), auto_views=False)
