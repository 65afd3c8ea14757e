"""A PettingZoo view of a learning trial (:mod:`sim.trial`) in which every robot learns, as agent ``robot_<i>``.

Usage::

    from sim.envs import pettingzoo_env

    par = pettingzoo_env.parallel_env()                       # ParallelEnv: all agents act at once, under the
                                                              # run's default formulation (or formulation=...)
    observations, infos = par.reset(seed=0)
    observations, rewards, terminations, truncations, infos = par.step(
        {agent: par.action_space(agent).sample() for agent in par.agents}
    )
    aec = pettingzoo_env.env()                                # the same game as an AEC env (parallel_to_aec)
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.conversions import parallel_to_aec

from sim.config import scenario
from sim.controllers import N_ACTIONS
from sim.features import coverage
from sim.formulation import Formulation, default_formulation
from sim.trial import TrialState, reset_trial, step_trial


class CmommtParallelEnv(ParallelEnv[str, np.ndarray, np.int64]):
    """All m robots act at once with ``Discrete(8)`` moves of the formulation's action set, each held for
    ``action_steps`` steps; ``formulation`` defaults to the run's (:func:`sim.formulation.default_formulation`).

    Robots start within sensing range of a target. Under the paper's trial rules a robot that loses every target gets
    ``lost_reward`` at that simulation step, leaves the episode and stays motionless in the arena [paper]; at the end
    of the learning trial every remaining robot gets its delayed reward (the formulation's) and the episode ends; a
    per-decision reward is paid after every action instead, and a time-out that bootstraps truncates the episode.
    """

    metadata: dict[str, Any] = {"name": "cmommt_v1", "render_modes": [], "is_parallelizable": True}  # noqa: RUF012

    def __init__(self, scenario_name: str = "cmommt-v1", formulation: Formulation | None = None) -> None:
        self.cfg = scenario(scenario_name)
        self.formulation = formulation or default_formulation()
        self.possible_agents = [f"robot_{i}" for i in range(self.cfg.n_robots)]
        self.agents: list[str] = []
        self._index = {name: i for i, name in enumerate(self.possible_agents)}
        self._state: TrialState | None = None
        self._decide = np.ones((1, self.cfg.n_robots), dtype=bool)
        self._rng = np.random.default_rng()
        self.render_mode = None

    @functools.cache  # noqa: B019 - PettingZoo requires the same space object on every call
    def observation_space(self, agent: str) -> spaces.Box:
        mask = self.cfg.mask_value
        return spaces.Box(-mask, mask, shape=(self.formulation.dim,), dtype=np.float32)

    @functools.cache  # noqa: B019 - PettingZoo requires the same space object on every call
    def action_space(self, agent: str) -> spaces.Discrete:
        return spaces.Discrete(N_ACTIONS)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        learners = np.ones(self.cfg.n_robots, dtype=bool)
        state = reset_trial(self.cfg, 1, learners, self.formulation, self._rng)
        self._state, self._decide = state, np.ones(state.shape, dtype=bool)
        self.agents = list(self.possible_agents)
        share = float(coverage(self.cfg, state.obs)[0])
        observations = {a: state.require_features()[0, i].copy() for i, a in enumerate(self.agents)}
        infos = {a: {"n_seen": int(state.obs.n_seen[0, i]), "coverage": share} for i, a in enumerate(self.agents)}
        return observations, infos

    def step(
        self, actions: dict[str, np.int64]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        state = self._state
        if state is None:
            raise RuntimeError("call reset() before step()")
        missing = set(self.agents) - set(actions)
        if missing:
            raise ValueError(f"no action for {', '.join(sorted(missing))}")
        chosen = np.zeros(state.shape, dtype=np.int64)
        for agent, action in actions.items():
            if agent not in self.agents:
                raise ValueError(f"{agent!r} is not an active agent")
            if not 0 <= int(action) < N_ACTIONS:
                raise ValueError(f"invalid action {action!r} for {agent}; expected an integer in [0, {N_ACTIONS})")
            chosen[0, self._index[agent]] = int(action)
        # Every live robot's tuple ends within this env step: when its action has lasted action_steps, when it
        # loses every target (then its s′ and reward are those of that simulation step), or at the end of the trial.
        pending = self._decide.copy()
        decide = self._decide
        next_obs, reward = state.require_features()[0].copy(), np.zeros(self.cfg.n_robots, np.float32)
        done, n_seen = np.zeros(self.cfg.n_robots, dtype=bool), state.obs.n_seen[0].copy()
        cut = np.zeros(self.cfg.n_robots, dtype=bool)
        while pending.any():
            state, out = step_trial(self.cfg, state, chosen, decide, self._rng)
            ends = (out.transition & pending)[0]
            next_obs = np.where(ends[:, None], out.require_next_features()[0], next_obs)
            reward = np.where(ends, out.reward[0], reward)
            done = np.where(ends, out.done[0], done)
            cut = np.where(ends, out.truncated[0], cut)
            n_seen = np.where(ends, state.obs.n_seen[0], n_seen)
            pending &= ~out.transition
            decide = out.decide
        self._state, self._decide = state, decide
        share = float(coverage(self.cfg, state.obs)[0])
        ids = [self._index[a] for a in self.agents]
        observations = {a: next_obs[i].copy() for a, i in zip(self.agents, ids, strict=True)}
        rewards = {a: float(reward[i]) for a, i in zip(self.agents, ids, strict=True)}
        terminations = {a: bool(done[i]) for a, i in zip(self.agents, ids, strict=True)}
        truncations = {a: bool(cut[i]) for a, i in zip(self.agents, ids, strict=True)}
        infos: dict[str, dict[str, Any]] = {
            a: {"n_seen": int(n_seen[i]), "coverage": share} for a, i in zip(self.agents, ids, strict=True)
        }
        self.agents = [a for a in self.agents if not (terminations[a] or truncations[a])]
        return observations, rewards, terminations, truncations, infos


def parallel_env(scenario_name: str = "cmommt-v1", formulation: Formulation | None = None) -> CmommtParallelEnv:
    """PettingZoo's ``parallel_env()`` constructor."""
    return CmommtParallelEnv(scenario_name, formulation)


def env(
    scenario_name: str = "cmommt-v1", formulation: Formulation | None = None
) -> AECEnv[str, np.ndarray, np.int64 | None]:
    """PettingZoo's ``env()`` constructor: the parallel game as an AEC env, agents taking turns."""
    return parallel_to_aec(parallel_env(scenario_name, formulation))
