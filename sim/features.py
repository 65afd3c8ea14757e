"""State featurizers, trial-end rewards and metric A, computed from an :class:`~sim.world.Observation`.

Both RL formulations of the paper [paper §4, Fernández & Parker 2001]:

* ``local2d``: (dx, dy) to the furthest (or nearest, by config) target in view; mask (1000, 1000) when none.
* ``collab6d``: nearest target, furthest target, nearest robot in view; each pair masked when absent.

Rewards are delayed to the end of a trial: ``local`` gives Σ_j b_ij(T); ``collab`` gives Σ_j b_ij(T) − k(T) with
k(T) = 2 when another robot is in view [paper Eq. 2]. A robot that sees no target gets ``lost_reward`` instead.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from sim.config import ScenarioConfig
from sim.world import Observation

Featurizer = Literal["local2d", "collab6d"]
FEATURIZERS: dict[str, int] = {"local2d": 2, "collab6d": 6}
"""State dimension of each featurizer."""

_LOCAL_COLUMNS = {"furthest": slice(2, 4), "nearest": slice(0, 2)}


def featurize(cfg: ScenarioConfig, obs: Observation, featurizer: str) -> np.ndarray:
    """(E, m, d) float32 states of every robot under ``featurizer``."""
    if featurizer == "collab6d":
        return obs.features
    if featurizer == "local2d":
        return np.ascontiguousarray(obs.features[..., _LOCAL_COLUMNS[cfg.local_target]])
    raise ValueError(f"unknown featurizer {featurizer!r}; known: {', '.join(FEATURIZERS)}")


def lost(obs: Observation) -> np.ndarray:
    """(E, m) bool: the robot observes no target [paper: it gets a negative reward and stays motionless]."""
    return obs.n_seen == 0


def trial_reward(cfg: ScenarioConfig, obs: Observation, featurizer: str) -> np.ndarray:
    """(E, m) float32 reward at the end of a trial (or when the robot loses all targets)."""
    seen = obs.n_seen.astype(np.float32)
    if featurizer == "collab6d":
        reward = seen - np.float32(cfg.robot_in_view_penalty) * obs.sees_robot.astype(np.float32)
    elif featurizer == "local2d":
        reward = seen
    else:
        raise ValueError(f"unknown featurizer {featurizer!r}; known: {', '.join(FEATURIZERS)}")
    return np.where(lost(obs), np.float32(cfg.lost_reward), reward).astype(np.float32)


def coverage(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    """(E,) float64: percentage of targets observed by at least one robot, this step (the summand of metric A)."""
    return 100.0 * obs.covered / cfg.n_targets
