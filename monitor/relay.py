"""The monitor of an actor whose viewer rows the learner logs (``--rerun learner``, what ``ennc-ql up`` gives its
actors): the actor opens no recording and loads no Rerun, which would cost it ≈ 70 MB of its memory
(docs/performance.md); its figures and sampled arena frames travel to the learner as ``ActorView`` messages
(docs/reference/protocol.md), best effort, and the learner logs them on the actor's own timelines.

Usage (an actor process)::

    monitor = RelayMonitor(partial(transport.publish, transport.keys.view("actor-0")), "actor-0")
    monitor.use_clock(run_clock)                            # train_time: seconds since the actor's loop began
    monitor.arena(paths.actor_arena("actor-0"), robots, targets, sensing_range=150.0, arena_radius=1000.0,
                  sim_step=t)                               # buffered
    monitor.actor_metrics("actor-0", sim_step=t, coverage=58.1, mean_reward=0.7, tuples_per_s=1e5)  # sends one view

Only what an actor logs is relayed: :meth:`arena` and :meth:`actor_metrics`; other calls do nothing.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import numpy as np

from monitor.interface import Monitor, actor_figures
from protocol.messages import MAX_VIEW_FRAMES, ActorView

log = logging.getLogger(__name__)


class RelayMonitor(Monitor):
    """Hands an actor's viewer rows to ``send`` as :class:`~protocol.messages.ActorView` messages: one per
    :meth:`actor_metrics` call, carrying the arena frames logged since the previous one (and one more whenever
    ``MAX_VIEW_FRAMES`` frames wait). A view that cannot be built or sent is logged and dropped: monitoring never
    stops an actor."""

    def __init__(self, send: Callable[[ActorView], object], actor_id: str) -> None:
        self.send = send
        self.actor_id = actor_id
        opened = time.monotonic()
        self._clock: Callable[[], float] = lambda: time.monotonic() - opened
        self._frames: list[tuple[int, float, np.ndarray, np.ndarray]] = []
        self._ranges = (1.0, 1.0)
        self._closed = False
        self.sent = 0
        self.dropped = 0

    @property
    def enabled(self) -> bool:
        return not self._closed

    def use_clock(self, clock: Callable[[], float]) -> None:
        self._clock = clock

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
        """Buffer a frame of this actor's arena (``origin`` is always ``paths.actor_arena(actor_id)`` here)."""
        if self._closed:
            return
        robots = np.asarray(robot_pos, np.float32).reshape(-1, 2).copy()
        targets = np.asarray(target_pos, np.float32).reshape(-1, 2).copy()
        self._frames.append((sim_step, self._clock(), robots, targets))
        self._ranges = (float(sensing_range), float(arena_radius))
        if len(self._frames) >= MAX_VIEW_FRAMES:
            self._relay(sim_step, {})

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
        self._relay(sim_step, actor_figures(coverage, mean_reward, tuples_per_s, policy_version))

    def _relay(self, sim_step: int, counters: dict[str, float]) -> None:
        frames, self._frames = self._frames, []
        robots, targets = self._stacked(frames)
        try:
            view = ActorView(
                actor_id=self.actor_id,
                sim_step=int(sim_step),
                train_time=float(self._clock()),
                wall_time=time.time(),
                counters=counters,
                frame_step=np.array([f[0] for f in frames], np.uint64),
                frame_time=np.array([f[1] for f in frames], np.float64),
                robot_pos=robots,
                target_pos=targets,
                sensing_range=self._ranges[0],
                arena_radius=self._ranges[1],
            )
            self.send(view)
        except Exception as exc:  # whatever fails, the view is dropped: monitoring never stops an actor
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 100 == 0:
                log.warning("%s: a view for the learner dropped (%d so far): %s", self.actor_id, self.dropped, exc)
            return
        self.sent += 1

    @staticmethod
    def _stacked(frames: list[tuple[int, float, np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        if not frames:
            return np.zeros((0, 0, 2), np.float32), np.zeros((0, 0, 2), np.float32)
        return np.stack([f[2] for f in frames]), np.stack([f[3] for f in frames])

    def close(self) -> None:
        self._closed = True
