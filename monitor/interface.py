"""The monitor interface; this base class is also the no-op monitor that ``--rerun off`` gives.

Every method of :class:`Monitor` returns at once and nothing here imports Rerun, so call sites log
unconditionally; guard only work done *to prepare* a call (``if monitor.enabled: ...``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from types import TracebackType
from typing import TYPE_CHECKING, Self

import numpy as np

from monitor import paths

if TYPE_CHECKING:
    from protocol.messages import ActorView
    from sim.formulation import Formulation


def resident_mb() -> float | None:
    """Resident memory of this process (MB) from ``/proc`` (Linux, where runs happen); None without it."""
    try:
        with open("/proc/self/statm") as statm:
            pages = int(statm.read().split()[1])
    except OSError:
        return None
    return pages * os.sysconf("SC_PAGE_SIZE") / 1e6


def actor_figures(
    coverage: float | None, mean_reward: float | None, tuples_per_s: float | None, policy_version: int | None
) -> dict[str, float]:
    """An actor's trial figures by series name (``monitor.paths``), with this process's memory; None left out."""
    figures = {
        paths.ACTOR_COVERAGE: coverage,
        paths.ACTOR_REWARD: mean_reward,
        paths.ACTOR_TUPLES_PER_S: tuples_per_s,
        paths.ACTOR_POLICY_VERSION: policy_version,
        paths.ACTOR_RSS: resident_mb(),
    }
    return {name: float(value) for name, value in figures.items() if value is not None}


class Monitor:
    """Where a process sends what it wants watched. See :mod:`monitor` for the call sequence.

    Timelines: every call takes the sequence timelines that apply as keyword arguments (``sim_step``,
    ``policy_version``, ``learner_step``); exactly those, plus ``train_time`` (the clock of :meth:`use_clock`) and
    ``wall_time`` (now), are attached to what it logs.
    """

    @property
    def enabled(self) -> bool:
        """False for the no-op monitor: skip computing what would only be logged."""
        return False

    def use_clock(self, clock: Callable[[], float]) -> None:
        """Stamp ``train_time`` with ``clock()`` (seconds of training) from now on; until called, the seconds since
        the monitor was opened."""

    def scalars(
        self,
        prefix: str,
        values: Mapping[str, float],
        *,
        sim_step: int | None = None,
        policy_version: int | None = None,
        learner_step: int | None = None,
    ) -> None:
        """Log each ``values[name]`` as a time series at ``<prefix>/<name>``, named ``name`` in the viewer."""

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
        """One arena at one step under ``origin`` (``paths.actor_arena(actor_id)`` or ``paths.EVAL_ARENA``).

        ``robot_pos`` (m, 2) and ``target_pos`` (n, 2) in arena units. Draws the boundary and the north-up transform
        (static, once per origin and radius), the sensing disks, the robots, and the targets in
        :data:`monitor.style.OBSERVED` when observed (within ``sensing_range`` of a robot), else
        :data:`monitor.style.UNOBSERVED`.
        """

    def prototypes(
        self, prototypes: Sequence[np.ndarray], q_values: Sequence[np.ndarray], *, policy_version: int
    ) -> None:
        """Each action's prototypes at ``learner/prototypes/action_<k>``, projected to 2-D, coloured by Q.

        ``prototypes[k]`` (p_k, d) in arena units (the views' fixed range is the sensing range), ``q_values[k]``
        (p_k,). See :func:`monitor.geometry.project_2d` for the projection and :func:`monitor.geometry.q_colors`
        for colours; the key's Q scale is labelled with this policy's Q range.
        """

    def q_stats(self, q_tables: Sequence[np.ndarray], *, policy_version: int, learner_step: int | None = None) -> None:
        """Mean, min and max over every finite entry of ``q_tables`` at ``learner/q/{mean,min,max}``."""

    def formulation(self, formulation: Formulation) -> None:
        """The formulation the policy is learned with: its state and reward name the learning curve, its state and
        moves lay out the prototype views (call before the curve starts and before the layout)."""

    def eval_coverage(self, coverage: float, *, policy_version: int, learner_step: int | None = None) -> None:
        """Metric A (%) of the current policy on the test trials, at ``learner/coverage/eval`` (the learning curve);
        the reference levels are drawn again at the same time, so that they span the curve."""

    def reference_levels(self, levels: Mapping[str, float]) -> None:
        """Metric A (%) of hand-made controllers (by ``sim.HAND_MADE`` name) on the same test trials as
        :meth:`eval_coverage`, at ``learner/coverage/reference/<name>``: flat lines from now on, drawn again with
        every evaluation point."""

    def final_coverage(
        self, coverage: float, *, trials: int, policy_version: int, learner_step: int | None = None
    ) -> None:
        """The final figure (%) on ``trials`` test trials, a marker of its own at ``learner/coverage/final``: it is
        measured on more trials than the curve's points, so it is not joined to them."""

    def cooperation(
        self,
        rows: Mapping[str, Mapping[str, float]],
        *,
        trials: int,
        policy_version: int,
        learner_step: int | None = None,
    ) -> None:
        """How each team spreads over the targets on ``trials`` test trials, per robot-step (``learned`` and every
        reference by ``sim.CONTROLLERS`` name; ``sim.rollout.Cooperation.summary``'s figures, with ``coverage`` and
        the paired ``learned_minus`` where known): a table at ``learner/cooperation``."""

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
        """The learner's status figures; ``lag`` maps actor id to policy versions behind (``learner/lag/<id>``).

        The process's resident memory is logged with them (``learner/rss_mb``).
        """

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
        """An actor's training figures at ``actors/<actor_id>/...``; figures left ``None`` are not logged.

        ``coverage`` (%) over its arenas, ``mean_reward`` per learning trial, ``policy_version`` it acts with; the
        process's resident memory is logged with them (``actors/<actor_id>/rss_mb``).
        """

    def actor_view(self, view: ActorView) -> None:
        """What an actor relayed (``--rerun learner``): its figures and arena frames, logged as :meth:`actor_metrics`
        and :meth:`arena` log an actor's own, on the actor's timelines (its ``sim_step``, ``train_time`` and wall
        time), so a recording reads the same whichever process wrote the rows."""

    def send_blueprint(
        self,
        actor_ids: Sequence[str] = (),
        *,
        eval_trial: bool = False,
        arena_radius: float | None = None,
        sensing_range: float | None = None,
    ) -> None:
        """Lay the viewer out (see :func:`monitor.layout.default_blueprint`) and log the colour key: for training,
        the curves, an arena view per actor and the rose of prototype views, one per move; for ``eval_trial``
        (replaying a test trial) the trial and its coverage.

        ``arena_radius`` and ``sensing_range`` fix the 2-D views' ranges (None: fitted to the data); with
        ``sensing_range`` the prototype views get their static axes and sensing circle.
        """

    def close(self) -> None:
        """Flush what is logged and close the sink; later calls are ignored."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
