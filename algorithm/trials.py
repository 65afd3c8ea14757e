"""A simulator slice: E arenas with all m robots running learning trials, vectorized over arenas and robots.

The trial rules live in :mod:`sim.trial` [paper §4; choices as tagged]: ``learning_steps`` steps long; learning
robots start within sensing range of a random target [choice]; an action of the formulation's set lasts
``action_steps`` steps (or, for VQQL, until the discretized state changes); the formulation's reward, by default
delayed to the end of the trial; under the paper's rules a learning robot that loses every target gets
``lost_reward``, its trial ends and it stays motionless [paper]. This slice chooses the
actions: robots that do not learn follow the current policy greedily (random before there is one) and search like
test-time robots when lost; it turns every finished action of a learner into a tuple.

Usage::

    sl = ExperienceSlice(cfg, SliceConfig(formulation, n_arenas=256), seed=0)
    batch = sl.run_trial()                      # random exploration: Transitions of every learning robot
    batch = sl.run_trial(agent, update=True)    # ε-greedy phase 2, updating the agent's tables on-line
    sl.stream_trial(send, agent, update=True)   # the same, each step's tuples handed to send(Transitions) at once
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from algorithm.agent import NStepReturns, TabularAgent
from algorithm.policy import ActionMode
from algorithm.transitions import Transitions
from sim import ScenarioConfig
from sim.formulation import Formulation
from sim.guide import Guide
from sim.rollout import StepHook
from sim.trial import TrialState, TrialStep, explore_actions, reset_trial, step_trial
from sim.world import WorldState, reset


@dataclass(frozen=True, slots=True)
class SliceConfig:
    formulation: Formulation
    """The learners' state, reward and trial rules, and every robot's action set."""
    n_arenas: int = 256
    """E, arenas simulated side by side."""
    learning_robots: tuple[int, ...] | None = None
    """Robot ids that learn and emit tuples; None = every robot (option 2)."""
    action_mode: ActionMode = "fixed"
    """``fixed`` (ENNC-QL) or ``until_change`` (VQQL) [paper]."""
    max_action_steps: int = 20
    """Cap of ``until_change`` actions [choice]."""

    def __post_init__(self) -> None:
        if self.n_arenas < 1:
            raise ValueError("n_arenas must be at least 1")
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
        self._world: WorldState | None = None
        """Where the last trial left the arenas (``continuing`` trial rules)."""
        self._trials = 0

    def run_trial(
        self, agent: TabularAgent | None = None, update: bool = False, on_step: StepHook | None = None
    ) -> Transitions:
        """One learning trial in every arena, its tuples in one batch; ``agent`` None means random actions for every
        robot.

        ``on_step`` (optional) sees the world and observation after every step, e.g. to draw an arena.
        """
        parts: list[Transitions] = []
        self.stream_trial(parts.append, agent, update, on_step)
        return Transitions.concat(parts) if parts else Transitions.empty(self.config.formulation.dim)

    def stream_trial(
        self,
        sink: Callable[[Transitions], None],
        agent: TabularAgent | None = None,
        update: bool = False,
        on_step: StepHook | None = None,
    ) -> None:
        """:meth:`run_trial`, each step's tuples handed to ``sink`` as the step ends instead of kept: an actor sends
        them as its messages fill, so it never holds a whole trial's tuples (tens of MB at 500 arenas)."""
        cfg, setup, rng = self.cfg, self.config, self.rng
        state = reset_trial(cfg, setup.n_arenas, self.learner_mask, setup.formulation, rng, self._carried(agent))
        # VQQL actions last until the held action's cell changes, so they need the agent's discretization.
        until_change = setup.action_mode == "until_change" and agent is not None
        hold = setup.max_action_steps if until_change else cfg.action_steps
        decide = np.ones(state.shape, dtype=bool)
        cell_sa = np.zeros(state.shape, np.int64)  # cell of (s, a) for the held action, for Eq. 1 and VQQL
        # (E·m, L) every robot's cells at the latest state searched for it. A state is searched once: the decision
        # made in it and the update of the tuple ending in it (its s′) read the same row.
        cells = None if agent is None else agent.cells(_flat(state.require_features()))
        returns = agent.returns(state.shape[0] * state.shape[1]) if agent is not None and update else None
        idle = np.zeros(state.shape, dtype=bool)
        while True:
            action, cell_sa = self._decide(agent, state, decide, cell_sa, update, cells)
            # The slice keeps only the newest state, so its tracks need no copy per step.
            # VQQL reads every step's cells for its cell-change boundary; other holds end together, so the states
            # between decisions are never read.
            state, out = step_trial(cfg, state, action, decide, rng, hold=hold, in_place=True, lazy=not until_change)
            if on_step is not None:
                on_step(state.world, state.obs)
            if out.next_features is None and not out.trial_over:
                # A lazy step on which no action ended (four in five): no tuple ends, nobody decides next.
                decide = idle
                continue
            if agent is not None and cells is not None:
                # Robots that decide next (none after the last step), and learners whose tuple ends here and
                # bootstraps from s′ (VQQL: all, for the cell-change boundary). Rows of ended trials keep older cells
                # that Eq. 1 does not read.
                if until_change:
                    need = np.ones(state.shape, bool)
                else:
                    need = (out.transition & ~out.done) | (out.decide & (not out.trial_over))
                rows = np.flatnonzero(need)
                if rows.size == need.size:  # a decision step: every robot, no gather and scatter
                    cells = agent.cells(_flat(state.require_features()))
                elif rows.size:
                    cells[rows] = agent.cells(_flat(state.require_features())[rows])
                if until_change:
                    now = np.take_along_axis(cells.reshape(*state.shape, -1), out.action[..., None], axis=2)[..., 0]
                    out = out.with_boundary(now != cell_sa)
            self._emit(out, agent if update else None, returns, cell_sa, cells, sink)
            if out.trial_over:
                self._world = state.world
                return
            decide = out.decide

    def _carried(self, agent: TabularAgent | None) -> WorldState | None:
        """The arenas the next trial starts in under ``continuing`` rules: the last trial's, or fresh ones as a test
        trial's (not beside a target) once per test trial's length; None: fresh arenas beside a target. Random
        exploration (no ``agent``) always starts beside a target: in fresh arenas random moves rarely find one, and
        phase 1 would fit its cells on states with nothing in view."""
        cfg = self.cfg
        if agent is None or not self.config.formulation.trial_rules.continuing:
            return None
        episode = max(1, cfg.test_steps // cfg.learning_steps)
        fresh = self._world is None or self._trials % episode == 0
        self._trials += 1
        return reset(cfg, self.config.n_arenas, self.rng) if fresh else self._world

    def _emit(
        self,
        out: TrialStep,
        updated: TabularAgent | None,
        returns: NStepReturns | None,
        cell_sa: np.ndarray,
        cells: np.ndarray | None,
        sink: Callable[[Transitions], None],
    ) -> None:
        """Hand the tuples that end on this step to ``sink``; with ``updated``, apply Eq. 1 to them (through
        ``returns``, the trial's unfinished targets, with n-step targets)."""
        # Rows of the (E·m) robots, found once for every array instead of once per boolean mask.
        rows = np.flatnonzero(out.transition)
        if rows.size == 0:
            return
        robots = rows % out.action.shape[1]
        # Held actions end together, so on a decision step every robot's tuple ends: views then, not copies (no
        # step writes into an array a TrialStep returned).
        take = slice(None) if rows.size == out.action.size else rows
        batch = Transitions(
            robot=robots.astype(np.int16),
            state=_flat(out.start_features)[take],
            action=out.action.reshape(-1)[take].astype(np.uint8),
            reward=out.reward.reshape(-1)[take],
            next_state=_flat(out.require_next_features())[take],
            done=out.done.reshape(-1)[take],
        )
        if updated is not None and cells is not None:
            held, next_cells = cell_sa.reshape(-1)[take], cells[take]
            if returns is not None:
                ends = batch.done | out.truncated.reshape(-1)[take]
                returns.update(rows, robots, held, next_cells, batch.reward, batch.done, ends)
            else:
                updated.update(robots, held, next_cells, batch.reward, batch.done)
        sink(batch)

    def _decide(
        self,
        agent: TabularAgent | None,
        state: TrialState,
        decide: np.ndarray,
        cell_sa: np.ndarray,
        explore: bool,
        all_cells: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(E, m) actions, read where ``decide``, and the cell of (s, a) of every robot's held action.

        ``all_cells`` (E·m, L) holds the cells of the deciding robots' states. Learners explore ε-greedily when
        ``explore``; the other robots act greedily.
        """
        if not decide.any():
            return state.action, cell_sa
        if agent is None or all_cells is None:
            return explore_actions(self.cfg, state, self.rng), cell_sa
        m = state.shape[1]
        who = np.flatnonzero(decide)
        cells = all_cells if who.size == all_cells.shape[0] else all_cells[who]  # every robot: a view
        robots = who % m
        learner_rows = self.learner_mask[robots]
        chosen = agent.act(robots, cells, self.rng, explore=False)
        guide = state.formulation.trial_rules.guide
        if explore and learner_rows.any() and guide is not None and guide.epsilon > 0:
            led_by = partial(_guided, guide, self.cfg, state, who)
            chosen = np.where(learner_rows, agent.explore(chosen, self.rng, led_by, guide.epsilon), chosen)
        elif explore and learner_rows.any():
            chosen[learner_rows] = agent.explore(chosen[learner_rows], self.rng)
        action = state.action.reshape(-1).copy()
        action[who] = chosen
        new_cell_sa = cell_sa.reshape(-1).copy()
        new_cell_sa[who] = cells[np.arange(who.size), chosen]
        return action.reshape(state.shape), new_cell_sa.reshape(state.shape)


def _guided(guide: Guide, cfg: ScenarioConfig, state: TrialState, who: np.ndarray, led: np.ndarray) -> np.ndarray:
    """(k,) the guide's moves of the deciding robots ``who[led]``."""
    return guide.actions(cfg, state, who[led])


def _flat(features: np.ndarray) -> np.ndarray:
    """(E·m, d) view of (E, m, d) states."""
    return features.reshape(-1, features.shape[-1])
