"""A simulator slice: E arenas with all m robots running learning trials, vectorized over arenas and robots.

The trial rules live in :mod:`sim.trial` [paper §4; choices as tagged]: ``learning_steps`` steps long; learning
robots start within sensing range of a random target [choice]; a compass action lasts ``action_steps`` steps (or,
for VQQL, until the discretized state changes); the reward is delayed to the end of the trial; a learning robot
that loses every target gets ``lost_reward``, its trial ends and it stays motionless [paper]. This slice chooses the
actions: robots that do not learn follow the current policy greedily (random before there is one) and search like
test-time robots when lost; it turns every finished action of a learner into a tuple.

Usage::

    sl = ExperienceSlice(cfg, SliceConfig(n_arenas=256), seed=0)
    batch = sl.run_trial()                      # random exploration: Transitions of every learning robot
    batch = sl.run_trial(agent, learn=True)     # ε-greedy phase 2, updating the agent's tables on-line
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithm.agent import TabularAgent
from algorithm.policy import ActionMode
from algorithm.transitions import Transitions
from sim import FEATURIZERS, ScenarioConfig
from sim.rollout import StepHook
from sim.trial import TrialState, random_actions, reset_trial, step_trial


@dataclass(frozen=True, slots=True)
class SliceConfig:
    n_arenas: int = 256
    """E, arenas simulated side by side."""
    featurizer: str = "collab6d"
    learning_robots: tuple[int, ...] | None = None
    """Robot ids that learn and emit tuples; None = every robot (option 2)."""
    action_mode: ActionMode = "fixed"
    """``fixed`` (ENNC-QL) or ``until_change`` (VQQL) [paper]."""
    max_action_steps: int = 20
    """Cap of ``until_change`` actions [choice]."""

    def __post_init__(self) -> None:
        if self.n_arenas < 1:
            raise ValueError("n_arenas must be at least 1")
        if self.featurizer not in FEATURIZERS:
            raise ValueError(f"unknown featurizer {self.featurizer!r}")
        if self.action_mode not in ("fixed", "until_change"):
            raise ValueError(f"action_mode must be 'fixed' or 'until_change', got {self.action_mode!r}")


class ExperienceSlice:
    """Runs whole learning trials in E arenas; each call returns the tuples of one trial."""

    def __init__(self, cfg: ScenarioConfig, config: SliceConfig, seed: int | np.random.SeedSequence = 0) -> None:
        self.cfg = cfg
        self.config = config
        self.rng = np.random.default_rng(seed)
        learners = range(cfg.n_robots) if config.learning_robots is None else config.learning_robots
        self.learner_mask = np.zeros(cfg.n_robots, dtype=bool)
        self.learner_mask[list(learners)] = True

    def run_trial(
        self, agent: TabularAgent | None = None, learn: bool = False, on_step: StepHook | None = None
    ) -> Transitions:
        """One learning trial in every arena; ``agent`` None means random actions for every robot.

        ``on_step`` (optional) sees the world and observation after every step, e.g. to draw an arena.
        """
        cfg, sc, rng = self.cfg, self.config, self.rng
        state = reset_trial(cfg, sc.n_arenas, self.learner_mask, sc.featurizer, rng)
        # VQQL actions last until the held action's cell changes, so they need the agent's discretization.
        until_change = sc.action_mode == "until_change" and agent is not None
        hold = sc.max_action_steps if until_change else cfg.action_steps
        robot_ids = np.broadcast_to(np.arange(cfg.n_robots), state.shape)
        decide = np.ones(state.shape, dtype=bool)
        cell_sa = np.zeros(state.shape, np.int64)  # cell of (s, a) for the held action, for Eq. 1 and VQQL
        parts: list[Transitions] = []
        while True:
            action, cell_sa = self._decide(agent, state, decide, cell_sa, learn)
            state, out = step_trial(cfg, state, action, decide, rng, hold=hold)
            if on_step is not None:
                on_step(state.world, state.obs)
            cells = None
            if until_change and agent is not None:
                cells = agent.cells(state.features.reshape(-1, state.features.shape[-1])).reshape(*state.shape, -1)
                now = np.take_along_axis(cells, out.action[..., None], axis=2)[..., 0]
                out = out.with_boundary(now != cell_sa)
            emit = out.transition
            if emit.any():
                batch = Transitions(
                    robot=robot_ids[emit].astype(np.int16),
                    state=out.start_features[emit],
                    action=out.action[emit].astype(np.uint8),
                    reward=out.reward[emit],
                    next_state=out.next_features[emit],
                    done=out.done[emit],
                )
                parts.append(batch)
                if learn and agent is not None:
                    next_cells = agent.cells(batch.next_state) if cells is None else cells[emit]
                    agent.learn(robot_ids[emit], cell_sa[emit], next_cells, batch.reward, batch.done)
            if out.trial_over:
                return Transitions.concat(parts) if parts else Transitions.empty(FEATURIZERS[sc.featurizer])
            decide = out.decide

    def _decide(
        self,
        agent: TabularAgent | None,
        state: TrialState,
        decide: np.ndarray,
        cell_sa: np.ndarray,
        explore: bool,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(E, m) actions, read where ``decide``, and the cell of (s, a) of every robot's held action.

        Learners explore ε-greedily when ``explore``; the other robots act greedily.
        """
        if not decide.any():
            return state.action, cell_sa
        if agent is None:
            return random_actions(state, self.rng), cell_sa
        m = state.shape[1]
        who = np.flatnonzero(decide)
        cells = agent.cells(state.features.reshape(-1, state.features.shape[-1])[who])
        robots = who % m
        learner_rows = self.learner_mask[robots]
        chosen = agent.act(robots, cells, self.rng, explore=False)
        if explore and learner_rows.any():
            chosen[learner_rows] = agent.act(robots[learner_rows], cells[learner_rows], self.rng, explore=True)
        action = state.action.reshape(-1).copy()
        action[who] = chosen
        new_cell_sa = cell_sa.reshape(-1).copy()
        new_cell_sa[who] = cells[np.arange(who.size), chosen]
        return action.reshape(state.shape), new_cell_sa.reshape(state.shape)
