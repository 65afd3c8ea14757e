"""A PettingZoo ``ParallelEnv`` view of CMOMMT: every robot is an agent named ``robot_<i>``."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sim.config import scenario
from sim.controllers import N_ACTIONS, compass_velocity
from sim.features import FEATURIZERS, featurize, lost, trial_reward
from sim.world import Observation, WorldState, reset, sense, step


class CmommtParallelEnv(ParallelEnv[str, np.ndarray, np.int64]):
    """All m robots act at once with ``Discrete(8)`` compass actions.

    A robot that loses every target gets ``lost_reward``, leaves the episode and stays motionless in the arena
    [paper]; at the end of the learning trial every remaining robot gets its delayed reward and the episode ends.
    """

    metadata: dict[str, Any] = {"name": "cmommt_v1", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012

    def __init__(self, scenario_name: str = "cmommt-v1", featurizer: str = "collab6d") -> None:
        if featurizer not in FEATURIZERS:
            raise ValueError(f"unknown featurizer {featurizer!r}; known: {', '.join(FEATURIZERS)}")
        self.cfg = scenario(scenario_name)
        self.featurizer = featurizer
        self.possible_agents = [f"robot_{i}" for i in range(self.cfg.n_robots)]
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        self._world: WorldState | None = None
        self._obs: Observation | None = None
        self._rng = np.random.default_rng()
        self.render_mode = None

    @functools.cache  # noqa: B019 - PettingZoo requires the same space object on every call
    def observation_space(self, agent: str) -> spaces.Box:
        mask = self.cfg.mask_value
        return spaces.Box(-mask, mask, shape=(FEATURIZERS[self.featurizer],), dtype=np.float32)

    @functools.cache  # noqa: B019 - PettingZoo requires the same space object on every call
    def action_space(self, agent: str) -> spaces.Discrete:
        return spaces.Discrete(N_ACTIONS)

    def _observations(self) -> dict[str, np.ndarray]:
        assert self._obs is not None
        feats = featurize(self.cfg, self._obs, self.featurizer)[0]
        return {a: feats[self._index[a]].copy() for a in self.agents}

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self._world = reset(self.cfg, 1, self._rng)
        self._obs = sense(self.cfg, self._world, self._rng)
        self.agents = list(self.possible_agents)
        return self._observations(), {a: {} for a in self.agents}

    def step(
        self, actions: dict[str, np.int64]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        if self._world is None or self._obs is None:
            raise RuntimeError("call reset() before step()")
        active = np.zeros(self.cfg.n_robots, dtype=bool)
        chosen = np.zeros(self.cfg.n_robots, dtype=np.int64)
        for agent, action in actions.items():
            if agent not in self.agents:
                raise ValueError(f"{agent!r} is not an active agent")
            if not 0 <= int(action) < N_ACTIONS:
                raise ValueError(f"invalid action {action!r} for {agent}; expected an integer in [0, {N_ACTIONS})")
            active[self._index[agent]] = True
            chosen[self._index[agent]] = int(action)
        velocity = np.where(active[:, None], compass_velocity(self.cfg, chosen), 0.0)[None]
        for _ in range(self.cfg.action_steps):
            self._world = step(self.cfg, self._world, velocity, self._rng)
            self._obs = sense(self.cfg, self._world, self._rng)
            if self._world.t >= self.cfg.learning_steps:
                break
        observations = self._observations()
        trial_over = self._world.t >= self.cfg.learning_steps
        gone = lost(self._obs)[0]
        rewards_now = trial_reward(self.cfg, self._obs, self.featurizer)[0]
        rewards: dict[str, float] = {}
        terminations: dict[str, bool] = {}
        for agent in self.agents:
            i = self._index[agent]
            done = trial_over or bool(gone[i])
            terminations[agent] = done
            rewards[agent] = float(rewards_now[i]) if done else 0.0
        truncations = {a: False for a in self.agents}
        infos: dict[str, dict[str, Any]] = {
            a: {"n_seen": int(self._obs.n_seen[0, self._index[a]])} for a in self.agents
        }
        self.agents = [a for a in self.agents if not terminations[a]]
        return observations, rewards, terminations, truncations, infos
