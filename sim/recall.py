"""A robot's own memory of the last target it saw, for the states that remember (``Featurizer.recalls``).

The honest A-CMOMMT keeps tracking a target after it leaves view, from its own sightings, and leaves one to a
teammate who reports seeing it [Parker; docs/learning-quality.md]; the learned states of :mod:`sim.features` forget
it the step it leaves. A :class:`Recall` keeps, per robot, which target was its nearest at its last sighting of any
target, that target's world position then, and the steps since. :func:`recall` turns an observation into the *view* a
remembering state reads: a robot that sees no target, but saw one at most ``cfg.recall_steps`` steps ago that no
teammate sees now, sees its remembered position as its nearest target (``n_seen`` 1, not shared), and
:attr:`~sim.world.Observation.age` gives every robot's steps since it sensed that pair (0 for a sighting now). The
target frame, the state and who searches (:func:`sim.features.lost`) are read from the view, so a robot that lost its
target decides, in a frame whose x points back at it, whether to return or to search; rewards and metric A keep
reading what is sensed.

It reads only what the robot knows: its own position (odometry, as the honest law's prediction needs), its own past
sightings, and which targets its teammates see now (the reports A-CMOMMT assumes). A memory a teammate covers is
hidden, not forgotten: returning to a watched target piles robots onto it (a force law fed the memory without this
rule scores 4.7 points less on training trials, docs/learning-quality.md "Eighth round"). Usage::

    memory = forget_all(obs.n_seen.shape)
    view, memory = recall(cfg, world, obs, memory)      # every step, after sense()
    features = formulation.featurizer.compute(cfg, view)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sim.config import ScenarioConfig
from sim.world import Observation, WorldState

NEVER = np.iinfo(np.int64).max // 2
"""The age of a memory that holds nothing (no target seen yet)."""


@dataclass(frozen=True, slots=True)
class Recall:
    """Every robot's memory of its last sighting, for E arenas × m robots."""

    point: np.ndarray
    """(E, m, 2) float64: the world position of the nearest target at the last step the robot saw a target."""
    age: np.ndarray
    """(E, m) int64: steps since that sighting (0: it sees a target now; :data:`NEVER`: it has seen none)."""
    target: np.ndarray
    """(E, m) int64: which target that was (its index, 0 before any sighting)."""


def forget_all(shape: tuple[int, int]) -> Recall:
    """A memory holding nothing, for (E, m) robots."""
    return Recall(point=np.zeros((*shape, 2)), age=np.full(shape, NEVER, np.int64), target=np.zeros(shape, np.int64))


def _in_view(cfg: ScenarioConfig, world: WorldState) -> tuple[np.ndarray, np.ndarray]:
    """(E, m, n) bool: robot i senses target j (what :func:`sim.world.sense` counts), and (E, m) int64: the index
    of each robot's nearest target in view (0 where none is)."""
    offset = world.target_pos[:, None, :, :] - world.robot_pos[:, :, None, :]
    d2 = np.einsum("emnk,emnk->emn", offset, offset)
    in_view = d2 <= cfg.sensing_range * cfg.sensing_range
    return in_view, np.where(in_view, d2, np.inf).argmin(axis=-1)


def recall(cfg: ScenarioConfig, world: WorldState, obs: Observation, memory: Recall) -> tuple[Observation, Recall]:
    """The view of ``obs`` with remembered targets filled in (module docstring), and the memory after this step.

    ``world`` is the state ``obs`` was sensed in; ``memory`` the one :func:`recall` returned on the step before, or
    :func:`forget_all` at the start of a trial.
    """
    seeing = obs.n_seen >= 1
    in_view, nearest_target = _in_view(cfg, world)
    nearest = obs.features[..., 0:2].astype(np.float64)
    point = np.where(seeing[..., None], world.robot_pos + nearest, memory.point)
    age = np.where(seeing, 0, np.minimum(memory.age + 1, NEVER))
    target = np.where(seeing, nearest_target, memory.target)
    after = Recall(point=point, age=age, target=target)
    # Robot i sees nothing, so whoever sees its remembered target now is a teammate.
    watched = np.take_along_axis(in_view.any(axis=1), target, axis=1)
    remembered = ~seeing & (age <= cfg.recall_steps) & ~watched
    if not remembered.any():
        return dataclasses.replace(obs, age=age), after
    features = obs.features.copy()
    features[..., 0:2] = np.where(
        remembered[..., None], (point - world.robot_pos).astype(np.float32), obs.features[..., 0:2]
    )
    view_shared = obs.shared.copy()
    view_shared[..., 0] &= ~remembered
    view = dataclasses.replace(
        obs,
        features=features,
        n_seen=np.where(remembered, 1, obs.n_seen).astype(np.int32),
        shared=view_shared,
        age=age,
    )
    return view, after


def view_of(
    cfg: ScenarioConfig, world: WorldState, obs: Observation, memory: Recall | None
) -> tuple[Observation, Recall | None]:
    """:func:`recall` for a caller that holds a memory only when its state remembers (``memory`` None: ``obs`` is
    the view, and there is nothing to keep)."""
    return (obs, None) if memory is None else recall(cfg, world, obs, memory)
