"""A Gymnasium single-robot view of a learning trial (:mod:`sim.trial`): robot 0 learns, the others do not.

Usage::

    import gymnasium
    import sim.envs  # registers the ids
    from sim.formulation import FORMULATIONS

    env = gymnasium.make("cmommt/SingleRobot-v1")             # the run's default formulation, or e.g.
    env = CmommtSingleRobotEnv(formulation=FORMULATIONS["paper"])
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    info["coverage"]                                           # % of targets observed now (metric A's summand)
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sim.config import scenario
from sim.controllers import HAND_MADE, N_ACTIONS, Controller
from sim.features import coverage
from sim.formulation import Formulation, default_formulation
from sim.trial import TrialState, explore_actions, reset_trial, step_trial


class CmommtSingleRobotEnv(gym.Env[np.ndarray, np.int64]):
    """Robot 0 of one arena acts through ``Discrete(8)`` moves of the formulation's action set; observations are its
    state under the formulation's featurizer (default: the run's default formulation,
    :func:`sim.formulation.default_formulation`).

    One env step is one action of robot 0: ``action_steps`` simulation steps, or fewer when it loses every target.
    Under the paper's trial rules the episode terminates at the end of the learning trial with the delayed reward, or
    earlier with ``lost_reward`` when robot 0 sees no target [paper; choice]; a formulation whose time-out bootstraps
    truncates it instead. ``others`` moves robots 1…m−1: ``"random"`` (default) is the experience slice's
    exploration rule (a random action every ``action_steps`` steps,
    searching when lost); any other name of :data:`~sim.controllers.HAND_MADE`, or a
    :class:`~sim.controllers.Controller`, drives them instead.
    """

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 - gymnasium reads it as a class attribute

    def __init__(
        self,
        scenario_name: str = "cmommt-v1",
        formulation: Formulation | None = None,
        others: str | Controller = "random",
    ) -> None:
        self.cfg = scenario(scenario_name)
        self.formulation = formulation or default_formulation()
        self.others: Controller | None = None
        if others != "random":
            self.others = HAND_MADE[others] if isinstance(others, str) else others
        mask = self.cfg.mask_value
        self.observation_space = spaces.Box(-mask, mask, shape=(self.formulation.dim,), dtype=np.float32)
        self.action_space = spaces.Discrete(N_ACTIONS)
        self._learner = np.arange(self.cfg.n_robots) == 0
        self._state: TrialState | None = None
        self._decide = np.ones((1, self.cfg.n_robots), dtype=bool)
        self._memory: Any = None

    def _info(self, state: TrialState) -> dict[str, Any]:
        return {"n_seen": int(state.obs.n_seen[0, 0]), "coverage": float(coverage(self.cfg, state.obs)[0])}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        rng = self.np_random
        self._state = reset_trial(self.cfg, 1, self._learner, self.formulation, rng)
        if self.others is not None:
            self._memory = self.others.init(self.cfg, self._state.world, rng)
        self._decide = np.ones(self._state.shape, dtype=bool)
        return self._state.require_features()[0, 0].copy(), self._info(self._state)

    def step(self, action: np.int64) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        state = self._state
        if state is None:
            raise RuntimeError("call reset() before step()")
        if not state.active[0, 0]:
            raise RuntimeError("the episode has terminated; call reset()")
        if not self.action_space.contains(action):
            raise ValueError(f"invalid action {action!r}; expected an integer in [0, {N_ACTIONS})")
        rng = self.np_random
        decide = self._decide
        while True:
            # Drawn only when someone decides, as the slice does, so both follow one random stream.
            actions = (
                explore_actions(self.cfg, state, rng) if self.others is None and decide.any() else state.action.copy()
            )
            actions[0, 0] = action
            velocity = None
            if self.others is not None:
                velocity, self._memory = self.others.act(self.cfg, state.world, state.obs, self._memory, rng)
            state, out = step_trial(self.cfg, state, actions, decide, rng, velocity=velocity)
            decide = out.decide
            if out.transition[0, 0]:
                break
        self._state, self._decide = state, decide
        obs = out.require_next_features()[0, 0].copy()
        return obs, float(out.reward[0, 0]), bool(out.done[0, 0]), bool(out.truncated[0, 0]), self._info(state)
