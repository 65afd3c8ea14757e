"""A simulator slice: E arenas with all m robots running learning trials, vectorized over arenas and robots.

Learning trials follow the paper [paper §4; choices as tagged]: ``learning_steps`` steps long; learning robots
start within sensing range of a random target [choice]; a compass action lasts ``action_steps`` steps (or, for
VQQL, until the discretized state changes); the reward is delayed to the end of the trial; a learning robot that
loses every target gets ``lost_reward``, its trial ends and it stays motionless [paper]. Robots that do not learn
follow the current policy greedily (random before there is one) and search like test-time robots when lost.

Usage::

    sl = ExperienceSlice(cfg, SliceConfig(n_arenas=256), seed=0)
    batch = sl.run_trial()                      # random exploration: Transitions of every learning robot
    batch = sl.run_trial(agent, learn=True)     # ε-greedy phase 2, updating the agent's tables on-line
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from algorithm.agent import TabularAgent
from algorithm.transitions import Transitions
from sim import FEATURIZERS, N_ACTIONS, ScenarioConfig
from sim.controllers import compass_velocity, wander
from sim.features import featurize, lost, trial_reward
from sim.rollout import StepHook
from sim.world import place_near_targets, reset, sense, step


@dataclass(frozen=True, slots=True)
class SliceConfig:
    n_arenas: int = 256
    """E, arenas simulated side by side."""
    featurizer: str = "collab6d"
    learners: tuple[int, ...] | None = None
    """Robot ids that learn and emit tuples; None = every robot (option 2)."""
    action_mode: str = "fixed"
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
        learners = range(cfg.n_robots) if config.learners is None else config.learners
        self.learner_mask = np.zeros(cfg.n_robots, dtype=bool)
        self.learner_mask[list(learners)] = True
        self.trials = 0

    def run_trial(
        self, agent: TabularAgent | None = None, learn: bool = False, on_step: StepHook | None = None
    ) -> Transitions:
        """One learning trial in every arena; ``agent`` None means random actions for every robot.

        ``on_step`` (optional) sees the world and observation after every step, e.g. to draw an arena.
        """
        cfg, sc, rng = self.cfg, self.config, self.rng
        n_arenas, m = sc.n_arenas, cfg.n_robots
        is_learner = np.broadcast_to(self.learner_mask, (n_arenas, m))
        world = place_near_targets(cfg, reset(cfg, n_arenas, rng), is_learner, rng)
        obs = sense(cfg, world, rng)
        feats = featurize(cfg, obs, sc.featurizer)
        robot_ids = np.broadcast_to(np.arange(m), (n_arenas, m))
        active = is_learner.copy()  # learners whose trial has not ended
        angle = rng.uniform(0.0, 2.0 * np.pi, (n_arenas, m))
        heading = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
        everyone = np.ones((n_arenas, m), dtype=bool)
        action, cell_sa, cells = self._decide(agent, feats, everyone, np.zeros((n_arenas, m), np.int64), learn)
        s_dec = feats.copy()
        held = np.zeros((n_arenas, m), np.int64)
        parts: list[Transitions] = []
        for t in range(1, cfg.learning_steps + 1):
            velocity = compass_velocity(cfg, action)
            heading = wander(cfg, world, heading)
            searching = ~is_learner & lost(obs)
            velocity = np.where(searching[..., None], cfg.robot_speed * heading, velocity)
            frozen = is_learner & ~active
            velocity = np.where(frozen[..., None], 0.0, velocity)
            world = step(cfg, world, velocity, rng)
            obs = sense(cfg, world, rng)
            if on_step is not None:
                on_step(world, obs)
            feats = featurize(cfg, obs, sc.featurizer)
            held += 1
            trial_over = t == cfg.learning_steps
            if sc.action_mode == "fixed" or agent is None:
                boundary = np.broadcast_to(held >= cfg.action_steps, (n_arenas, m))
                cells = None
            else:
                cells = agent.cells(feats.reshape(n_arenas * m, -1)).reshape(n_arenas, m, -1)
                now = np.take_along_axis(cells, action[..., None], axis=2)[..., 0]
                boundary = (now != cell_sa) | (held >= sc.max_action_steps)
            done = active & (lost(obs) | trial_over)
            emit = active & (boundary | done)
            if emit.any():
                reward = np.where(done, trial_reward(cfg, obs, sc.featurizer), 0.0).astype(np.float32)
                batch = Transitions(
                    robot=robot_ids[emit].astype(np.int16),
                    state=s_dec[emit],
                    action=action[emit].astype(np.uint8),
                    reward=reward[emit],
                    next_state=feats[emit],
                    done=done[emit],
                )
                parts.append(batch)
                if learn and agent is not None:
                    next_cells = agent.cells(batch.next_state) if cells is None else cells[emit]
                    agent.learn(robot_ids[emit], cell_sa[emit], next_cells, batch.reward, batch.done)
            active &= ~done
            if trial_over:
                break
            decide = boundary & (active | ~is_learner)
            if decide.any():
                new_action, new_cell, _ = self._decide(agent, feats, decide, action, learn)
                action = np.where(decide, new_action, action)
                cell_sa = np.where(decide, new_cell, cell_sa)
                s_dec = np.where(decide[..., None], feats, s_dec)
                held = np.where(decide, 0, held)
        self.trials += 1
        return Transitions.concat(parts) if parts else Transitions.empty(FEATURIZERS[sc.featurizer])

    def _decide(
        self,
        agent: TabularAgent | None,
        feats: np.ndarray,
        decide: np.ndarray,
        current: np.ndarray,
        explore: bool,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """New actions (E, m) for the robots in ``decide`` and the cell of (s, a) for each."""
        n_arenas, m = decide.shape
        if agent is None:
            return self.rng.integers(0, N_ACTIONS, (n_arenas, m)), np.zeros((n_arenas, m), np.int64), None
        who = np.nonzero(decide.reshape(-1))[0]
        states = feats.reshape(n_arenas * m, -1)[who]
        cells = agent.cells(states)
        robots = who % m
        learner_rows = self.learner_mask[robots]
        chosen = agent.act(robots, cells, self.rng, explore=False)
        if explore and learner_rows.any():
            chosen[learner_rows] = agent.act(robots[learner_rows], cells[learner_rows], self.rng, explore=True)
        action = current.reshape(-1).copy()
        action[who] = chosen
        cell_sa = np.zeros(n_arenas * m, np.int64)
        cell_sa[who] = cells[np.arange(who.size), chosen]
        return action.reshape(n_arenas, m), cell_sa.reshape(n_arenas, m), cells
