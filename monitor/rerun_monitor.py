"""The monitor that logs to a Rerun recording stream. Importing this module imports Rerun and matplotlib: only
:func:`monitor.open_monitor` does, when a sink other than ``off`` is asked for."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import rerun as rr

from monitor import drawings, geometry, paths, style
from monitor.interface import Monitor, actor_figures, resident_mb
from monitor.layout import default_blueprint
from protocol.messages import ActorView
from sim.actions import ActionSet
from sim.controllers import N_ACTIONS
from sim.formulation import Formulation, default_formulation

log = logging.getLogger(__name__)

CLOSE_FLUSH_TIMEOUT_S = 10.0
"""How long :meth:`RerunMonitor.close` waits for buffered data to reach the sink before giving up with a warning."""

_ROBOT_COLOR = style.rgba(style.ROBOT)
_SENSING_COLOR = style.rgba(style.ROBOT, style.SENSING_ALPHA)
_OBSERVED_COLOR = style.rgba(style.OBSERVED)
_UNOBSERVED_COLOR = style.rgba(style.UNOBSERVED)
_BOUNDARY_COLOR = style.rgba(style.BOUNDARY)


class RerunMonitor(Monitor):
    """Logs into ``rec``, a stream whose sink is already set; :func:`monitor.open_monitor` builds one."""

    def __init__(self, rec: rr.RecordingStream, process: str) -> None:
        self.rec = rec
        self.process = process
        self._named: set[str] = set()
        self._boundaries: dict[str, float] = {}
        self._flipped: set[str] = set()
        self._references: dict[str, float] = {}
        self._learned = "learned policy"
        # Which state columns the prototypes are drawn at, and the moves their views are named and laid out by; the
        # run's default formulation until the learner names its own.
        self._formulation: Formulation | None = None
        opened = time.monotonic()
        self._clock: Callable[[], float] = lambda: time.monotonic() - opened
        self._closed = False
        self._lock = threading.Lock()

    @property
    def enabled(self) -> bool:
        return not self._closed

    def use_clock(self, clock: Callable[[], float]) -> None:
        self._clock = clock

    def _at(
        self,
        sim_step: int | None,
        policy_version: int | None,
        learner_step: int | None,
        clock: tuple[float, float] | None = None,
    ) -> None:
        """Set the timelines of the rows logged next; ``clock`` (train_time, wall_time) for rows of another process
        (an actor's relayed rows), else this process's clock and now."""
        # Rerun keeps the time cursor per thread and recording id (streams sharing an id in one thread share it);
        # resetting it first attaches exactly the timelines given to this call, whatever was set before.
        rec = self.rec
        rec.reset_time()
        if sim_step is not None:
            rec.set_time(paths.SIM_STEP, sequence=sim_step)
        if policy_version is not None:
            rec.set_time(paths.POLICY_VERSION, sequence=policy_version)
        if learner_step is not None:
            rec.set_time(paths.LEARNER_STEP, sequence=learner_step)
        train_time, wall_time = (self._clock(), time.time()) if clock is None else clock
        rec.set_time(paths.TRAIN_TIME, duration=train_time)
        rec.set_time(paths.WALL_TIME, timestamp=wall_time)

    def _first(self, path: str, seen: set[str]) -> bool:
        """True the first time ``path`` is asked about for ``seen`` (thread-safe: callers log from several threads)."""
        with self._lock:
            first = path not in seen
            seen.add(path)
        return first

    def _scalar(self, path: str, name: str, value: float, marker: rr.components.MarkerShape | None = None) -> None:
        """One point of a series named ``name``: a line, or points drawn as ``marker``."""
        if self._first(path, self._named):
            series: rr.SeriesLines | rr.SeriesPoints = (
                rr.SeriesLines(names=name)
                if marker is None
                else rr.SeriesPoints(names=name, markers=marker, marker_sizes=style.MARKER_SIZE)
            )
            self.rec.log(path, series, static=True)
        self.rec.log(path, rr.Scalars(float(value)))

    def _north_up(self, root: str) -> None:
        if self._first(root, self._flipped):
            self.rec.log(root, drawings.NORTH_UP, static=True)

    def scalars(
        self,
        prefix: str,
        values: Mapping[str, float],
        *,
        sim_step: int | None = None,
        policy_version: int | None = None,
        learner_step: int | None = None,
    ) -> None:
        if self._closed:
            return
        self._at(sim_step, policy_version, learner_step)
        for name, value in values.items():
            self._scalar(f"{prefix}/{name}", name, value)

    def arena(
        self,
        origin: str,
        robot_pos: np.ndarray,
        target_pos: np.ndarray,
        *,
        sensing_range: float,
        arena_radius: float,
        sim_step: int,
    ) -> None:
        if self._closed:
            return
        self._arena(origin, robot_pos, target_pos, sensing_range, arena_radius, sim_step, None)

    def _arena(
        self,
        origin: str,
        robot_pos: np.ndarray,
        target_pos: np.ndarray,
        sensing_range: float,
        arena_radius: float,
        sim_step: int,
        clock: tuple[float, float] | None,
    ) -> None:
        rec = self.rec
        with self._lock:
            new_boundary = self._boundaries.get(origin) != arena_radius
            self._boundaries[origin] = arena_radius
        self._north_up(origin)
        if new_boundary:
            outline = rr.LineStrips2D([geometry.circle(arena_radius)], colors=_BOUNDARY_COLOR)
            rec.log(f"{origin}/{paths.ARENA_BOUNDARY}", outline, static=True)
        robots = np.asarray(robot_pos, dtype=np.float64).reshape(-1, 2)
        targets = np.asarray(target_pos, dtype=np.float64).reshape(-1, 2)
        observed = geometry.observed_targets(robots, targets, sensing_range)
        target_colors = np.where(observed[:, None], _OBSERVED_COLOR, _UNOBSERVED_COLOR).astype(np.uint8)
        self._at(sim_step, None, None, clock)
        rec.log(
            f"{origin}/{paths.ARENA_SENSING}",
            rr.Points2D(robots, radii=sensing_range, colors=_SENSING_COLOR, draw_order=10.0),
        )
        rec.log(
            f"{origin}/{paths.ARENA_ROBOTS}",
            rr.Points2D(robots, radii=drawings.MARKER_RADIUS, colors=_ROBOT_COLOR, draw_order=20.0),
        )
        rec.log(
            f"{origin}/{paths.ARENA_TARGETS}",
            rr.Points2D(targets, radii=drawings.MARKER_RADIUS, colors=target_colors, draw_order=30.0),
        )

    def prototypes(
        self, prototypes: Sequence[np.ndarray], q_values: Sequence[np.ndarray], *, policy_version: int
    ) -> None:
        if self._closed:
            return
        if len(prototypes) != len(q_values):
            raise ValueError(f"{len(prototypes)} prototype arrays but {len(q_values)} Q arrays")
        colors = geometry.q_colors(q_values)
        self._at(None, policy_version, None)
        for k, (protos, q, rgba) in enumerate(zip(prototypes, q_values, colors, strict=True)):
            q = np.asarray(q, dtype=np.float64).reshape(-1)
            points = geometry.project_2d(protos, None if self._formulation is None else self._formulation.featurizer)
            if len(points) != len(q):
                raise ValueError(f"action {k}: {len(points)} prototypes but {len(q)} Q values")
            self._north_up(paths.prototypes_of(k))
            self.rec.log(
                paths.prototypes_of(k),
                rr.Points2D(points, radii=drawings.PROTOTYPE_RADIUS, colors=rgba),
                rr.AnyValues(q=q),
            )
        self.rec.log(paths.KEY_Q_ENDS, drawings.q_ends(*geometry.q_range(q_values)))

    def q_stats(self, q_tables: Sequence[np.ndarray], *, policy_version: int, learner_step: int | None = None) -> None:
        if self._closed:
            return
        flat = [np.asarray(t, dtype=np.float64).reshape(-1) for t in q_tables]
        entries = np.concatenate(flat) if flat else np.zeros(0)
        entries = entries[np.isfinite(entries)]
        if entries.size == 0:
            return
        stats = dict(zip(paths.Q_STATS, (entries.mean(), entries.min(), entries.max()), strict=True))
        self.scalars(paths.LEARNER_Q, stats, policy_version=policy_version, learner_step=learner_step)

    def formulation(self, formulation: Formulation) -> None:
        self._learned = f"learned policy ({formulation.featurizer.name}, {formulation.reward.name} reward)"
        self._formulation = formulation

    @property
    def _actions(self) -> ActionSet:
        return (self._formulation or default_formulation()).actions

    def eval_coverage(self, coverage: float, *, policy_version: int, learner_step: int | None = None) -> None:
        if self._closed:
            return
        self._at(None, policy_version, learner_step)
        self._scalar(paths.LEARNER_COVERAGE_EVAL, self._learned, coverage)
        self._log_references()

    def reference_levels(self, levels: Mapping[str, float]) -> None:
        if self._closed:
            return
        with self._lock:
            self._references.update(levels)
        self._at(None, None, None)
        self._log_references()

    def _log_references(self) -> None:
        """The levels at the current time: a flat line through every point of the curve."""
        with self._lock:
            levels = dict(self._references)
        for controller, level in levels.items():
            label, _ = style.REFERENCES[controller]
            self._scalar(paths.reference(controller), f"{label} {level:.1f}%", level)

    def final_coverage(
        self, coverage: float, *, trials: int, policy_version: int, learner_step: int | None = None
    ) -> None:
        if self._closed:
            return
        self._at(None, policy_version, learner_step)
        name = f"final, {trials} trials"
        self._scalar(paths.LEARNER_COVERAGE_FINAL, name, coverage, rr.components.MarkerShape.Diamond)
        self._log_references()

    def cooperation(
        self,
        rows: Mapping[str, Mapping[str, float]],
        *,
        trials: int,
        policy_version: int,
        learner_step: int | None = None,
    ) -> None:
        if self._closed:
            return
        self._at(None, policy_version, learner_step)
        self.rec.log(
            paths.LEARNER_COOPERATION,
            rr.TextDocument(style.cooperation_table(rows, trials), media_type="text/markdown"),
        )

    def learner_metrics(
        self,
        *,
        learner_step: int,
        policy_version: int,
        tuples_per_s: float,
        live_actors: int,
        store_size: int,
        rejected: int,
        lag: Mapping[str, int],
    ) -> None:
        if self._closed:
            return
        self._at(None, policy_version, learner_step)
        self._scalar(paths.LEARNER_POLICY_VERSION, "learner", policy_version)
        self._scalar(paths.LEARNER_TUPLES_PER_S, "learner", tuples_per_s)
        self._scalar(paths.LEARNER_LIVE_ACTORS, "live actors", live_actors)
        self._scalar(paths.LEARNER_STORE_SIZE, "tuples stored", store_size)
        self._scalar(paths.LEARNER_REJECTED, "rejected messages", rejected)
        rss = resident_mb()
        if rss is not None:
            self._scalar(paths.LEARNER_RSS, "learner", rss)
        for actor_id, behind in lag.items():
            self._scalar(paths.learner_lag(actor_id), actor_id, behind)

    def actor_metrics(
        self,
        actor_id: str,
        *,
        sim_step: int,
        coverage: float | None = None,
        mean_reward: float | None = None,
        tuples_per_s: float | None = None,
        policy_version: int | None = None,
    ) -> None:
        if self._closed:
            return
        figures = actor_figures(coverage, mean_reward, tuples_per_s, policy_version)
        self._at(sim_step, policy_version, None)
        for metric, value in figures.items():
            self._scalar(paths.actor(actor_id, metric), actor_id, value)

    def actor_view(self, view: ActorView) -> None:
        if self._closed:
            return
        origin = paths.actor_arena(view.actor_id)
        epoch = view.wall_time - view.train_time  # the actor's wall time at its train_time 0
        frames = zip(view.frame_step, view.frame_time, view.robot_pos, view.target_pos, strict=True)
        for step, at, robots, targets in frames:
            clock = (float(at), epoch + float(at))
            self._arena(origin, robots, targets, view.sensing_range, view.arena_radius, int(step), clock)
        version = view.counters.get(paths.ACTOR_POLICY_VERSION)
        self._at(view.sim_step, None if version is None else int(version), None, (view.train_time, view.wall_time))
        for metric, value in view.counters.items():
            self._scalar(paths.actor(view.actor_id, metric), view.actor_id, value)

    def send_blueprint(
        self,
        actor_ids: Sequence[str] = (),
        *,
        eval_trial: bool = False,
        arena_radius: float | None = None,
        sensing_range: float | None = None,
    ) -> None:
        if self._closed:
            return
        blueprint = default_blueprint(
            actor_ids,
            eval_trial=eval_trial,
            arena_radius=arena_radius,
            sensing_range=sensing_range,
            actions=self._actions,
        )
        self.rec.send_blueprint(blueprint)
        # The drawings the views are read against; static, so sending them again with a new layout costs nothing.
        for path, entry in drawings.key(q_scale=not eval_trial):
            self.rec.log(path, entry, static=True)
        if not eval_trial and sensing_range is not None:
            for k in range(N_ACTIONS):
                for path, part in drawings.prototype_frame(k, sensing_range, self._actions):
                    self.rec.log(path, part, static=True)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
        try:
            self.rec.flush(timeout_sec=CLOSE_FLUSH_TIMEOUT_S)
        except RuntimeError as exc:
            # An unreachable viewer or a server whose port was taken must not fail the process at exit.
            log.warning("%s: Rerun data not fully delivered: %s", self.process, exc)
        self.rec.disconnect()
        log.info("%s: Rerun monitor closed", self.process)
