"""A Gymnasium single-robot view of CMOMMT: robot 0 learns, the other robots follow a given controller."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sim.config import scenario
from sim.controllers import HAND_MADE, N_ACTIONS, Controller, compass_velocity
from sim.features import FEATURIZERS, featurize, lost, trial_reward
from sim.world import Observation, WorldState, place_near_targets, reset, sense, step


class CmommtSingleRobotEnv(gym.Env[np.ndarray, np.int64]):
    """Robot 0 of one arena acts through ``Discrete(8)`` compass actions; observations are its features.

    ``others`` names a hand-made controller (or is a :class:`~sim.controllers.Controller`) for robots 1…m−1.
    The episode terminates at the end of the learning trial with the delayed reward, or earlier with
    ``lost_reward`` when robot 0 sees no target.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - gymnasium reads it as a class attribute

    def __init__(
        self,
        scenario_name: str = "cmommt-v1",
        featurizer: str = "collab6d",
        others: str | Controller = "random",
    ) -> None:
        if featurizer not in FEATURIZERS:
            raise ValueError(f"unknown featurizer {featurizer!r}; known: {', '.join(FEATURIZERS)}")
        self.cfg = scenario(scenario_name)
        self.featurizer = featurizer
        self.others: Controller = HAND_MADE[others] if isinstance(others, str) else others
        mask = self.cfg.mask_value
        dim = FEATURIZERS[featurizer]
        self.observation_space = spaces.Box(-mask, mask, shape=(dim,), dtype=np.float32)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self._world: WorldState | None = None
        self._obs: Observation | None = None
        self._memory: Any = None

    def _observe(self) -> np.ndarray:
        assert self._obs is not None
        return featurize(self.cfg, self._obs, self.featurizer)[0, 0].copy()

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        world = reset(self.cfg, 1, rng)
        first = np.zeros((1, self.cfg.n_robots), dtype=bool)
        first[0, 0] = True
        self._world = place_near_targets(self.cfg, world, first, rng)
        self._memory = self.others.init(self.cfg, self._world, rng)
        self._obs = sense(self.cfg, self._world, rng)
        return self._observe(), {"n_seen": int(self._obs.n_seen[0, 0])}

    def step(self, action: np.int64) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._world is None or self._obs is None:
            raise RuntimeError("call reset() before step()")
        if not self.action_space.contains(action):
            raise ValueError(f"invalid action {action!r}; expected an integer in [0, {N_ACTIONS})")
        rng = self.np_random
        mine = compass_velocity(self.cfg, np.asarray(action, dtype=np.int64))
        for _ in range(self.cfg.action_steps):
            velocity, self._memory = self.others.act(self.cfg, self._world, self._obs, self._memory, rng)
            velocity[0, 0] = mine
            self._world = step(self.cfg, self._world, velocity, rng)
            self._obs = sense(self.cfg, self._world, rng)
            if lost(self._obs)[0, 0] or self._world.t >= self.cfg.learning_steps:
                break
        ended = bool(lost(self._obs)[0, 0]) or self._world.t >= self.cfg.learning_steps
        reward = float(trial_reward(self.cfg, self._obs, self.featurizer)[0, 0]) if ended else 0.0
        return self._observe(), reward, ended, False, {"n_seen": int(self._obs.n_seen[0, 0])}
