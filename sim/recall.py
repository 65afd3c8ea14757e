"""A robot's own tracks of the targets it saw, for the states that remember (``Featurizer.recalls``).

The honest A-CMOMMT keeps tracking a target after it leaves view, from its own sightings predicted forward, and leaves
one to a teammate who reports seeing it [Parker; docs/concepts/learning.md, "The references"]; the learned states of
:mod:`sim.features` forget it the step it leaves. A :class:`Recall` keeps, per robot and target, the robot's last
sighting of the target, the target's velocity estimated from its sightings, and the steps since (A-CMOMMT's own tracks).
Its *remembered target* is, of the targets it saw at most ``cfg.recall_steps`` steps ago that neither it nor any
teammate sees now, the one whose predicted position (beyond its sensing range) lies nearest.

:func:`recall` turns an observation into the *view* a remembering state reads:

* a robot that sees no target and remembers one sees the remembered target's predicted position as its nearest
  target (``n_seen`` 1, not shared), so its target frame points back at it and it decides instead of searching;
* a robot that sees a target and remembers another reads the remembered one's offset in
  :attr:`~sim.world.Observation.memory` (``remembers`` True);

rewards and metric A keep reading what is sensed.

It reads only what the robot knows: its own position (odometry, as the honest law's prediction needs), its own
sightings, and which targets its teammates see now (the reports A-CMOMMT assumes). A target a teammate sees is left
to it: returning to a watched target piles robots onto it (a force law fed a memory without this rule scored 4.7
points less on training trials: docs/notebook.md, "2026-12-04: a memory that leaves a watched target to its
teammate"). Usage::

    memory = forget_all(cfg, obs.n_seen.shape)
    view, memory = recall(cfg, world, obs, memory)      # every step, after sense()
    features = formulation.featurizer.compute(cfg, view)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sim import _kernels
from sim.config import ScenarioConfig
from sim.world import Observation, WorldState

NEVER = _kernels.NEVER_SEEN
"""The age of a track that holds nothing (the robot never saw that target)."""


@dataclass(frozen=True, slots=True)
class Recall:
    """Every robot's tracks of every target, for E arenas × m robots × n targets."""

    position: np.ndarray
    """(E, m, n, 2) float64: the target's world position at the robot's last sighting of it."""
    velocity: np.ndarray
    """(E, m, n, 2) float64: its displacement per step estimated from the robot's sightings (0 after a first one)."""
    age: np.ndarray
    """(E, m, n) int64: steps since that sighting (0: seen now; :data:`NEVER`: never seen)."""
    known: np.ndarray
    """(E, m, ⌈n / 32⌉) int64: bit j % 32 of word j // 32 set where the robot has a track of target j (its age is not
    :data:`NEVER`), so that an update reads only those tracks and the ones sighted now."""


def forget_all(cfg: ScenarioConfig, shape: tuple[int, int]) -> Recall:
    """Tracks holding nothing, for (E, m) robots and the scenario's targets."""
    tracks = (*shape, cfg.n_targets)
    return Recall(
        position=np.zeros((*tracks, 2)),
        velocity=np.zeros((*tracks, 2)),
        age=np.full(tracks, NEVER, np.int64),
        known=np.zeros((*shape, -(-cfg.n_targets // _kernels.TRACK_WORD)), np.int64),
    )


def recall(
    cfg: ScenarioConfig, world: WorldState, obs: Observation, memory: Recall, *, in_place: bool = False
) -> tuple[Observation, Recall]:
    """The view of ``obs`` with remembered targets filled in (module docstring), and the tracks after this step.

    ``world`` is the state ``obs`` was sensed in; ``memory`` the one :func:`recall` returned on the step before, or
    :func:`forget_all` at the start of a trial. ``memory`` is left as it was, unless ``in_place``: then the tracks
    after this step are ``memory`` itself, updated (a caller that keeps no earlier tracks saves copying them: the
    tracks were a fifth of a learning step).
    """
    if in_place:
        after = memory
    else:
        after = Recall(
            position=memory.position.copy(),
            velocity=memory.velocity.copy(),
            age=memory.age.copy(),
            known=memory.known.copy(),
        )
    offset = np.empty(world.robot_pos.shape)
    remembers = np.empty(obs.n_seen.shape, np.bool_)
    _kernels.update_tracks(
        world.robot_pos,
        world.target_pos,
        sightings(cfg, world) if obs.sighted is None else obs.sighted,
        after.position,
        after.velocity,
        after.age,
        after.known,
        cfg.sensing_range,
        cfg.recall_steps,
        offset,
        remembers,
    )
    # A robot that sees no target has both shared flags off already, so its remembered target reads as unshared.
    features = np.empty_like(obs.features)
    n_seen = np.empty_like(obs.n_seen)
    memory_now = np.empty(offset.shape, np.float32)
    also = np.empty_like(remembers)
    _kernels.remembered_view(obs.features, obs.n_seen, offset, remembers, features, n_seen, memory_now, also)
    view = dataclasses.replace(obs, features=features, n_seen=n_seen, memory=memory_now, remembers=also)
    return view, after


def view_of(
    cfg: ScenarioConfig, world: WorldState, obs: Observation, memory: Recall | None, *, in_place: bool = False
) -> tuple[Observation, Recall | None]:
    """:func:`recall` for a caller that holds a memory only when its state remembers (``memory`` None: ``obs`` is
    the view, and there is nothing to keep)."""
    return (obs, None) if memory is None else recall(cfg, world, obs, memory, in_place=in_place)


def sightings(cfg: ScenarioConfig, world: WorldState) -> np.ndarray:
    """(E, m, n) bool: robot i has target j within sensing range, measured as :func:`sim.world.sense` measures it."""
    dx = world.target_pos[:, None, :, 0] - world.robot_pos[:, :, None, 0]
    dy = world.target_pos[:, None, :, 1] - world.robot_pos[:, :, None, 1]
    return dx * dx + dy * dy <= cfg.sensing_range * cfg.sensing_range
