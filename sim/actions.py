"""Action sets: what a discrete action index means as a move, by name.

Every action set has 8 actions, each a full-speed move held for ``action_steps`` steps (or until the policy decides
again). A set names its directions in a *frame*: the world's axes for ``compass`` [paper], the frame of the
nearest target in view for ``relative``, or the frame of the force law's pull for ``law`` (:func:`law_frame`)
[beyond the paper], fixed when the robot decides::

    actions = ACTION_SETS["relative"]
    frame = actions.frame(obs)                        # (E, m, 2, 2) rows: the frame's x and y axes, world units
    velocity = actions.velocity(cfg, chosen, frame)   # (E, m, 2) displacement of every robot this step

The target frame (:func:`target_frame`): its x axis points from the robot to the nearest target in view; its y axis
is the x axis turned a quarter turn counter-clockwise, then mirrored so that the furthest target in view lies on
its +y side (or, with one target in view, the nearest robot in view; with neither, no mirror). A robot that sees no
target has the world's frame (it does not act on a policy then: it searches). In that frame a state and the move
chosen in it do not depend on the robot's heading in the world, nor on whether the scene is seen in a mirror, so
one cell of a discretization covers every rotation and reflection of one situation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import _kernels
from sim.config import ForceLawConfig, ScenarioConfig
from sim.controllers import COMPASS, COMPASS_NAMES, STATE_FORCE_LAW, wander
from sim.world import Observation, WorldState

_EIGHTHS = np.arange(8) * np.pi / 4
_TURNED = np.stack([np.cos(_EIGHTHS), np.sin(_EIGHTHS)], axis=-1)
"""(8, 2) unit vectors at multiples of 45° counter-clockwise: the directions of every relative set's moves."""
_NO_HEADING = np.zeros((1, 1, 2))
"""What the law frame's kernel is given for the headings when it does not read them."""


@dataclass(frozen=True, slots=True, eq=False)
class ActionSet:
    """Eight moves named in a frame: the world's (``relative=False``) or the nearest target's. Two sets are equal
    when their names, moves and frames are."""

    name: str
    moves: tuple[str, ...]
    """The move of each action index, in index order."""
    directions: np.ndarray
    """(8, 2) unit vectors of the moves in their frame."""
    relative: bool
    """Directions are in a robot's own frame, fixed when the robot decides: the target frame (:func:`target_frame`),
    or with ``law`` the law frame (:func:`law_frame`)."""
    law: ForceLawConfig | None = None
    """The force law whose pull is the frame's x axis (``law`` and ``law-search`` sets); None: the target frame's or
    the world's."""
    search: bool = False
    """Where the law pulls nowhere, x along the robot's search heading instead of the target frame's
    (``law-search``, ``law-track``)."""
    track: bool = False
    """The search heading follows the law: at every step it turns to the law's pull where the law pulls, and is kept
    (reflected off the wall) where it pulls nowhere, as the hand-made law's own heading is (``law-track``); False: a
    heading drawn at the trial's start, only ever reflected off the wall."""

    def steer(self, cfg: ScenarioConfig, world: WorldState, obs: Observation, heading: np.ndarray) -> np.ndarray:
        """(E, m, 2) every robot's search heading after this step (``track``): ``heading`` reflected off the wall,
        or, for a ``track`` set, the direction of the law's pull on ``obs`` wherever it pulls."""
        kept = wander(cfg, world, heading)
        if self.track:
            assert self.law is not None, "a track set is a law set"
            _kernels.pull_headings(law_force(obs, self.law), kept)
        return kept

    def frame(self, obs: Observation, heading: np.ndarray | None = None) -> np.ndarray:
        """(E, m, 2, 2) every robot's frame now: rows are its x and y axes in world coordinates. ``heading`` (E, m, 2)
        unit vectors: every robot's search heading, which a ``search`` set's frame needs (ValueError without)."""
        if self.law is not None:
            if self.search and heading is None:
                raise ValueError(f"the {self.name!r} moves are named from the search heading: pass every robot's")
            return law_frame(obs, self.law, heading if self.search else None)
        if self.relative:
            return target_frame(obs)
        return np.broadcast_to(np.eye(2), (*obs.n_seen.shape, 2, 2))

    def velocity(self, cfg: ScenarioConfig, actions: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """(…, 2) full-speed world displacement of action indices (…) in frames (…, 2, 2)."""
        if not self.relative:
            return cfg.robot_speed * self.directions[actions]
        actions = np.asarray(actions, np.int64)
        # The kernel walks (E, m): any other shape is laid out as one row of it.
        frames = np.broadcast_to(np.asarray(frame, np.float64), (*actions.shape, 2, 2)).reshape(1, -1, 2, 2)
        out = np.empty((1, actions.size, 2))
        _kernels.frame_velocity(self.directions, actions.reshape(1, -1), frames, cfg.robot_speed, out)
        return out.reshape(*actions.shape, 2)

    def closest(self, velocity: np.ndarray, frame: np.ndarray) -> np.ndarray:
        """(…,) the action index whose move is closest in direction to each world ``velocity`` (…, 2), in the frames
        (…, 2, 2) a robot would name it in (the world's for a set that is not relative): what a hand-made law's move
        is as an action of this set."""
        v = np.asarray(velocity, np.float64)
        if self.relative:
            v = np.stack([(frame[..., 0, :] * v).sum(-1), (frame[..., 1, :] * v).sum(-1)], axis=-1)
        return np.argmax(v @ self.directions.T, axis=-1)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ActionSet) and (self.name, self.moves, self.relative) == (
            other.name,
            other.moves,
            other.relative,
        )

    def __hash__(self) -> int:
        return hash((self.name, self.moves, self.relative))


RELATIVE_NAMES = ("toward", "toward-left", "left", "away-left", "away", "away-right", "right", "toward-right")
LAW_NAMES = ("law", "law-left", "left", "back-left", "back", "back-right", "right", "law-right")

ACTION_SETS: dict[str, ActionSet] = {
    a.name: a
    for a in (
        ActionSet("compass", COMPASS_NAMES, COMPASS, relative=False),
        ActionSet("relative", RELATIVE_NAMES, _TURNED, relative=True),
        ActionSet("law", LAW_NAMES, _TURNED, relative=True, law=STATE_FORCE_LAW),
        ActionSet("law-search", LAW_NAMES, _TURNED, relative=True, law=STATE_FORCE_LAW, search=True),
        ActionSet("law-track", LAW_NAMES, _TURNED, relative=True, law=STATE_FORCE_LAW, search=True, track=True),
    )
}
"""Every action set by name: ``compass``, the 8 compass moves, north = +y, clockwise [paper]; ``relative``, the 8
moves at multiples of 45° counter-clockwise from the direction of the nearest target in view, "left" meaning the
side of the furthest target (or of the nearest robot) [beyond the paper]; ``law``, the 8 moves at multiples of 45°
from the pull of the force law on the state's information (``force-6d-shared``, :data:`STATE_FORCE_LAW`, a
remembering state's remembered target included), "law" being that pull's own direction: a table that picks it
follows the law, one that picks another move departs from it [beyond the paper: the law's move as one of the
learned choices, in a frame that turns with the robot's exact situation inside a cell]; ``law-search``, the same
moves, but where the law pulls nowhere (every target in view watched by a teammate) named from the robot's search
heading, the way a lost robot searches, so that ``law`` there is the law's own move: leave and search along that
heading [beyond the paper]; ``law-track``, the ``law-search`` moves with a search heading that follows the law's
pull (:attr:`ActionSet.track`): where the law pulls nowhere, ``law`` goes on along its last pull, as the hand-made
law searches [beyond the paper]."""


def target_frame(obs: Observation) -> np.ndarray:
    """(E, m, 2, 2) float64 the target frame of every robot (module docstring): rows are its x and y axes.

    Read from the features' offsets (nearest target, furthest target, nearest robot in view), so it holds only what
    the robot senses. A numba kernel: the numpy version took half of a learning trial's time.
    """
    frame = np.empty((*obs.n_seen.shape, 2, 2))
    _kernels.target_frames(obs.features, obs.n_seen, obs.sees_robot, frame)
    return frame


def _remembered(obs: Observation) -> tuple[np.ndarray, np.ndarray]:
    """(E, m, 2) offsets of the remembered targets and (E, m) whether each robot remembers one (zeros, False for a
    view that does not remember)."""
    shape = obs.n_seen.shape
    memory = np.zeros((*shape, 2)) if obs.memory is None else np.asarray(obs.memory, np.float64)
    remembers = np.zeros(shape, bool) if obs.remembers is None else obs.remembers
    return memory, remembers


def _law_params(law: ForceLawConfig) -> np.ndarray:
    return np.array([law.do1, law.do2, law.do3, law.do4, law.dr1, law.dr2, law.shared_target_weight])


def law_force(obs: Observation, law: ForceLawConfig = STATE_FORCE_LAW) -> np.ndarray:
    """(E, m, 2) float64 the pull of the force law ``law`` on the observation's features (see :func:`law_frame`)."""
    force = np.empty((*obs.n_seen.shape, 2))
    _kernels.state_forces(
        obs.features, obs.n_seen, obs.sees_robot, obs.shared, *_remembered(obs), _law_params(law), force
    )
    return force


def law_frame(obs: Observation, law: ForceLawConfig = STATE_FORCE_LAW, heading: np.ndarray | None = None) -> np.ndarray:
    """(E, m, 2, 2) float64 the law frame of every robot: x along the pull of the force law ``law`` on the
    observation's features (the nearest and the furthest target in view, weighted ``shared_target_weight`` where a
    teammate sees them, the nearest robot in view, and a remembering view's remembered target), as
    :class:`sim.controllers.StateForceController` computes it; y a quarter turn counter-clockwise from x, mirrored
    as the target frame is (so a scene and its mirror image get mirrored moves, and one cell of the state covers
    both). Where the law pulls nowhere (every target in view watched by a teammate, no robot near), the target
    frame, or given ``heading`` (E, m, 2) x along each robot's search heading (y turned and mirrored as above). It
    reads what the state reads, and the robot's own heading."""
    target = target_frame(obs)
    memory, remembers = _remembered(obs)
    search = heading is not None
    headings = np.asarray(heading, np.float64) if search else _NO_HEADING
    frame = np.empty((*obs.n_seen.shape, 2, 2))
    _kernels.law_frames(
        obs.features,
        obs.n_seen,
        obs.sees_robot,
        obs.shared,
        memory,
        remembers,
        _law_params(law),
        target,
        headings,
        search,
        frame,
    )
    return frame
