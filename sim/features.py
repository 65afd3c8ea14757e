"""State featurizers and rewards by name, and metric A, computed from an :class:`~sim.world.Observation`.

Featurizers (:data:`FEATURIZER_REGISTRY`; :data:`FEATURIZERS` gives each one's dimension):

* ``local2d``: (dx, dy) to the furthest (or nearest, by config) target in view; mask (1000, 1000) when none
  [paper §4].
* ``collab6d``: nearest target, furthest target, nearest robot in view; each pair masked when absent [paper §4].
* ``shared8d``: ``collab6d`` and, for its nearest and its furthest target, 1 if another robot observes it too,
  else 0 (0 when the target is masked) [beyond the paper: the communication A-CMOMMT assumes, the attribute choice
  the paper names as future work].
* ``present10d``: ``shared8d`` with every absent pair at (0, 0) instead of the (1000, 1000) mask, and a presence bit
  for the furthest target (a second target in view) and for the robot [beyond the paper: standardized, the mask
  made the real offsets about 8x coarser than the distance between present and absent].
* ``frame9d``: the same content in the target frame of :func:`sim.actions.target_frame` (x towards the nearest
  target, mirrored so that the furthest target lies at y >= 0): the nearest target's distance, the furthest
  target's and the robot's (x, y) with presence bits, the two shared flags [beyond the paper: one cell covers
  every rotation and reflection of a situation; with the ``relative`` action set the moves are named in it too].
* ``frame11d-recall``: ``frame9d`` read from the view of :func:`sim.recall.recall`, and the direction of the robot's
  remembered target (a target it lost at most ``recall_steps`` steps ago and no teammate sees now, predicted from
  its own sightings) as a unit vector in the target frame, (0, 0) when it has none; a robot that sees no target
  reads its remembered one as its nearest instead [beyond the paper: the robot's own tracks of the targets it lost,
  as the honest A-CMOMMT keeps].

Rewards (:data:`REWARDS`), each given with the trial rules of :mod:`sim.trial`; a learning robot that loses every
target gets ``lost_reward`` instead and, under the paper's rules (:class:`sim.formulation.TrialRules`), its trial
ends:

* ``observed``: Σ_j b_ij(T) at the end of the trial [paper, local experiments].
* ``eq2``: Σ_j b_ij(T) − k(T), k(T) = ``robot_in_view_penalty`` when another robot is in view [paper Eq. 2].
* ``difference``: D_i(T) = G(z) − G(z without robot i) of metric A's summand at the end of the trial, i.e. the
  targets robot i observes and no other robot does [beyond the paper: Agogino & Tumer's difference reward].
* ``difference-decision``: the same D_i, earned at every step and paid at the end of each action as its mean over
  the action's steps (a reward per decision, so that credit need not travel back a whole trial) [beyond the paper].
* ``difference-redundancy``: the same, less ``redundancy_penalty`` for a step in which the robot sees only targets a
  teammate sees too: a redundant robot is told so at once, as A-CMOMMT with the teammate-observed weight at 0 lets
  it feel no pull [beyond the paper; the analogue of Eq. 2's k(T)].
* ``difference-shaped``: ``difference-redundancy`` plus the change of a potential over each step, Φ(s′) − Φ(s), with
  Φ = −``redundancy_potential`` × (1 − d / sensing range) for a robot that sees only teammate-watched targets, d
  the nearest one's distance, and 0 otherwise: a redundant robot is paid at once for every step that takes it
  away from the crowd, instead of only after the ~20 steps it takes to leave the view [beyond the paper;
  potential-based shaping, Ng, Harada & Russell 1999; undiscounted, so with the learner's γ < 1 it also charges a
  redundant step (1 − γ)Φ(s′), the same sign as the redundancy charge].

* ``coverage-split``: each target the robot observes, split evenly among the robots observing it, Σ_j b_ij / Σ_k
  b_kj, earned at every step and paid per decision as ``difference-decision`` is: the team's rewards sum to metric A's
  summand at every step, so a team policy that covers more targets earns more on average, which the difference
  rewards do not guarantee (a team that keeps some targets watched twice covers more and is paid less) [beyond the
  paper].

``paper`` names the featurizer's own reward of the paper: ``observed`` for ``local2d``, ``eq2`` for the collaborative
states. :mod:`sim.formulation` resolves the names of a formulation's parts into these objects, once.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from sim import _kernels
from sim.actions import target_frame
from sim.config import ScenarioConfig
from sim.world import Observation

_LOCAL_COLUMNS = {"furthest": slice(2, 4), "nearest": slice(0, 2)}
_COLLAB_STATE = (
    "nearest_target_dx",
    "nearest_target_dy",
    "furthest_target_dx",
    "furthest_target_dy",
    "nearest_robot_dx",
    "nearest_robot_dy",
)


@dataclass(frozen=True, slots=True)
class Featurizer:
    """A state definition: the columns of a robot's state and how they are computed from an observation."""

    name: str
    state: tuple[str, ...]
    """Column names, in order (the policy file's header lists them)."""
    compute: Callable[[ScenarioConfig, Observation], np.ndarray]
    """(E, m, d) float32 states of every robot."""
    paper_reward: str
    """The reward ``paper`` stands for with this state."""
    sees_none: Callable[[ScenarioConfig, np.ndarray], np.ndarray]
    """(…,) bool of states (…, d): the robot sees no target (phase 1's ``targets="lost"`` reads lost tuples by it)."""
    frame: str = "world"
    """The frame its offsets are given in: ``world`` (x east, y north) or ``target``
    (:func:`sim.actions.target_frame`)."""
    recalls: bool = False
    """It reads the view of :func:`sim.recall.recall` (a robot's remembered target), so a caller keeps every robot's
    :class:`~sim.recall.Recall` from step to step; False: the observation alone."""
    view: tuple[int, int] = (0, 1)
    """The two columns its prototypes are drawn at in the viewer and the policy figure: the nearest target's (dx, dy)
    for the world-frame states; for the target-frame ones the furthest target's (x, y) in that frame (x towards the
    nearest target adds no second axis of its own)."""

    @property
    def dim(self) -> int:
        return len(self.state)


def _nearest_masked(cfg: ScenarioConfig, states: np.ndarray) -> np.ndarray:
    # The first pair is the mask when no target is in view; a real offset never reaches it (mask > sensing range).
    return (states[..., 0] == np.float32(cfg.mask_value)) & (states[..., 1] == np.float32(cfg.mask_value))


def _distance_masked(cfg: ScenarioConfig, states: np.ndarray) -> np.ndarray:
    return states[..., 0] == np.float32(cfg.mask_value)


def _nearest_absent(nearest: slice, present: int, cfg: ScenarioConfig, states: np.ndarray) -> np.ndarray:
    """No target in view for the presence-coded states: the nearest target's columns are 0 and so is the furthest
    target's presence bit (a target exactly at the robot's position reads the same: a set of measure zero). Bound
    with :func:`functools.partial`, so that a formulation pickles (jobs run in worker processes)."""
    return (states[..., nearest] == 0).all(axis=-1) & (states[..., present] == 0)


def _local2d(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return np.ascontiguousarray(obs.features[..., _LOCAL_COLUMNS[cfg.local_target]])


def _collab6d(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return obs.features


def _shared8d(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return np.concatenate([obs.features, obs.shared.astype(np.float32)], axis=-1)


def _pairs(obs: Observation) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The three offsets of the features with absent pairs zeroed, and the presence of the furthest target (a second
    target in view) and of a robot in view, as float64."""
    f = obs.features.astype(np.float64)
    has_target = (obs.n_seen >= 1)[..., None]
    has_second = obs.n_seen >= 2
    nearest = np.where(has_target, f[..., 0:2], 0.0)
    furthest = np.where(has_second[..., None], f[..., 2:4], 0.0)
    robot = np.where(obs.sees_robot[..., None], f[..., 4:6], 0.0)
    return nearest, furthest, robot, has_second.astype(np.float64), obs.sees_robot.astype(np.float64)


def _present10d(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    nearest, furthest, robot, has_second, has_robot = _pairs(obs)
    columns = [nearest, furthest, has_second[..., None], robot, has_robot[..., None], obs.shared]
    return np.concatenate(columns, axis=-1).astype(np.float32)


def _frame7d(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    f = obs.features.astype(np.float64)
    frame = target_frame(obs)

    def local(offset: np.ndarray) -> np.ndarray:
        return np.einsum("...k,...dk->...d", offset, frame)

    has_target = obs.n_seen >= 1
    distance = np.where(has_target, np.linalg.norm(f[..., 0:2], axis=-1), cfg.mask_value)[..., None]
    furthest = np.where(has_target[..., None], local(f[..., 2:4]), cfg.mask_value)
    robot = np.where(obs.sees_robot[..., None], local(f[..., 4:6]), cfg.mask_value)
    return np.concatenate([distance, furthest, robot, obs.shared], axis=-1).astype(np.float32)


def _frame9d(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    out = np.empty((*obs.n_seen.shape, 9), np.float32)
    _kernels.frame9d(obs.features, obs.n_seen, obs.sees_robot, obs.shared, target_frame(obs), out)
    return out


def _frame11d_recall(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    out = np.empty((*obs.n_seen.shape, 11), np.float32)
    frame = target_frame(obs)
    # The kernel writes columns 0-8 of each row; the memory's direction fills 9 and 10.
    _kernels.frame9d(obs.features, obs.n_seen, obs.sees_robot, obs.shared, frame, out)
    if obs.memory is None:
        out[..., 9:] = 0.0
        return out
    _kernels.memory_direction(obs.memory, frame, out)
    return out


_FRAME9D = (
    "nearest_target_distance",
    "furthest_target_x",
    "furthest_target_y",
    "furthest_target_present",
    "nearest_robot_x",
    "nearest_robot_y",
    "nearest_robot_present",
    "nearest_target_shared",
    "furthest_target_shared",
)

FEATURIZER_REGISTRY: dict[str, Featurizer] = {
    f.name: f
    for f in (
        Featurizer("local2d", ("target_dx", "target_dy"), _local2d, "observed", _nearest_masked),
        Featurizer("collab6d", _COLLAB_STATE, _collab6d, "eq2", _nearest_masked),
        Featurizer(
            "shared8d",
            (*_COLLAB_STATE, "nearest_target_shared", "furthest_target_shared"),
            _shared8d,
            "eq2",
            _nearest_masked,
        ),
        Featurizer(
            "present10d",
            (
                "nearest_target_dx",
                "nearest_target_dy",
                "furthest_target_dx",
                "furthest_target_dy",
                "furthest_target_present",
                "nearest_robot_dx",
                "nearest_robot_dy",
                "nearest_robot_present",
                "nearest_target_shared",
                "furthest_target_shared",
            ),
            _present10d,
            "eq2",
            partial(_nearest_absent, slice(0, 2), 4),
        ),
        Featurizer(
            "frame7d",
            (
                "nearest_target_distance",
                "furthest_target_x",
                "furthest_target_y",
                "nearest_robot_x",
                "nearest_robot_y",
                "nearest_target_shared",
                "furthest_target_shared",
            ),
            _frame7d,
            "eq2",
            _distance_masked,
            frame="target",
            view=(1, 2),
        ),
        Featurizer(
            "frame9d",
            _FRAME9D,
            _frame9d,
            "eq2",
            partial(_nearest_absent, slice(0, 1), 3),
            frame="target",
            view=(1, 2),
        ),
        Featurizer(
            "frame11d-recall",
            (*_FRAME9D, "remembered_target_x", "remembered_target_y"),
            _frame11d_recall,
            "eq2",
            partial(_nearest_absent, slice(0, 1), 3),
            frame="target",
            recalls=True,
            view=(1, 2),
        ),
    )
}
"""Every featurizer by name."""
FEATURIZERS: dict[str, int] = {name: f.dim for name, f in FEATURIZER_REGISTRY.items()}
"""State dimension of each featurizer."""


@dataclass(frozen=True, slots=True)
class Reward:
    """A reward function: what a learning robot is paid at the end of its trial, or after each of its actions."""

    name: str
    value: Callable[[ScenarioConfig, Observation], np.ndarray]
    """(E, m) float32 value of the observation for every robot."""
    per_decision: bool
    """False: ``value`` at the last step of the trial, 0 before. True: ``value`` summed over an action's steps and
    paid as their mean when the action ends."""
    potential: Callable[[ScenarioConfig, Observation], np.ndarray] | None = None
    """(E, m) float32 Φ of an observation, or None: a per-decision reward's every step also pays Φ(after) − Φ(before)
    (:func:`step_value`)."""


def _observed(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return obs.n_seen.astype(np.float32)


def _eq2(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    penalty = np.float32(cfg.robot_in_view_penalty) * obs.sees_robot.astype(np.float32)
    return obs.n_seen.astype(np.float32) - penalty


def _difference(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return obs.n_only.astype(np.float32)


def _difference_redundancy(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    out = np.empty(obs.n_only.shape, np.float32)
    _kernels.difference_redundancy(obs.n_seen, obs.n_only, np.float32(cfg.redundancy_penalty), out)
    return out


def _coverage_split(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    if obs.sighted is None:
        raise ValueError("coverage-split reads which robot observes which target: an observation made by sense()")
    watchers = obs.sighted.sum(axis=1, keepdims=True)  # (E, 1, n) robots observing each target
    return (obs.sighted / np.maximum(watchers, 1)).sum(axis=-1).astype(np.float32)


def _redundancy_potential(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    redundant = (obs.n_seen > 0) & (obs.n_only == 0)
    closeness = 1.0 - np.hypot(obs.features[..., 0], obs.features[..., 1]) / cfg.sensing_range
    return np.where(redundant, -cfg.redundancy_potential * closeness, 0.0).astype(np.float32)


REWARDS: dict[str, Reward] = {
    r.name: r
    for r in (
        Reward("observed", _observed, per_decision=False),
        Reward("eq2", _eq2, per_decision=False),
        Reward("difference", _difference, per_decision=False),
        Reward("difference-decision", _difference, per_decision=True),
        Reward("difference-redundancy", _difference_redundancy, per_decision=True),
        Reward("difference-shaped", _difference_redundancy, per_decision=True, potential=_redundancy_potential),
        Reward("coverage-split", _coverage_split, per_decision=True),
    )
}
"""Every reward function by name; ``paper`` is accepted wherever a reward is named: the featurizer's own
(:meth:`sim.formulation.Formulation.of`)."""


def step_value(cfg: ScenarioConfig, before: Observation, after: Observation, reward: Reward) -> np.ndarray:
    """(E, m) float32 what a per-decision ``reward`` earns over the step from ``before`` to ``after``: its value at
    ``after``, plus the change of its potential if it has one."""
    value = reward.value(cfg, after)
    if reward.potential is None:
        return value
    return (value + reward.potential(cfg, after) - reward.potential(cfg, before)).astype(np.float32)


def featurize(cfg: ScenarioConfig, obs: Observation, featurizer: Featurizer) -> np.ndarray:
    """(E, m, d) float32 states of every robot under ``featurizer``."""
    return featurizer.compute(cfg, obs)


def lost(obs: Observation) -> np.ndarray:
    """(E, m) bool: the robot observes no target [paper: it gets a negative reward and stays motionless]."""
    return obs.n_seen == 0


def trial_reward(cfg: ScenarioConfig, obs: Observation, reward: Reward) -> np.ndarray:
    """(E, m) float32 reward of a trial-end ``reward`` at this observation, ``lost_reward`` for a lost robot."""
    return np.where(lost(obs), np.float32(cfg.lost_reward), reward.value(cfg, obs)).astype(np.float32)


def coverage(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    """(E,) float64: percentage of targets observed by at least one robot, this step (the summand of metric A)."""
    return 100.0 * obs.covered / cfg.n_targets
