"""Phase-2 tabular Q-learning agent over a fixed discretization (ENNC-QL phase 2, VQQL).

Usage::

    agent = TabularAgent(policy, Phase2Config())
    cells = agent.cells(states)                                        # (N, L) cell of each (s, a)
    actions = agent.act(robots, cells, rng, explore=True)              # ε-greedy on each robot's own table
    actions = agent.explore(greedy_actions, rng)                       # the same ε flips on greedy actions
    agent.update(robots, cell_sa, next_cells, rewards, dones)          # Eq. 1
    snapshot = agent.policy()
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.qtable import n_step_targets, q_targets, q_update, row_best
from sim import N_ACTIONS


@dataclass(frozen=True, slots=True)
class Phase2Config:
    """On-line Q-learning parameters [choice: α = 0.1, γ = 0.9, ε = 0.1]."""

    alpha: float = 0.1
    """Step size of Eq. 1 [choice]; with ``alpha_floor``, the step of a cell's first visit."""
    gamma: float = 0.9
    """Discount of Eq. 1 per decision [choice]."""
    epsilon: float = 0.1
    """Probability that a learning robot explores: a random action instead of its table's best [choice]."""
    alpha_floor: float | None = None
    """None: constant ``alpha`` [paper Eq. 1]. A number: the n-th visit of a cell steps by
    max(alpha_floor, 1 / (1/alpha − 1 + n)), a running mean of its targets in which the initial value weighs
    1/alpha − 1 samples, so that a cell visited often averages over about 1/alpha_floor targets instead of 1/alpha
    [beyond the paper: a decaying step size]."""
    n_step: int = 1
    """Decisions one target spans: r_t + γ r_t+1 + … + γ^(n−1) r_t+n−1 + γ^n max_b Q(s_t+n, b), cut short without
    the bootstrap where the robot's trial ends terminally [1: paper Eq. 1; beyond the paper: n-step returns, which
    carry a payoff that comes decisions later (a search's) back to the move that started it without bootstrapping
    through every aliased cell between]."""

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must lie in (0, 1], got {self.alpha}")
        if self.alpha_floor is not None and not 0.0 < self.alpha_floor <= self.alpha:
            raise ValueError(f"alpha_floor must lie in (0, alpha], got {self.alpha_floor}")
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"gamma must lie in [0, 1), got {self.gamma}")
        if not 0.0 <= self.epsilon <= 1.0:
            raise ValueError(f"epsilon must lie in [0, 1], got {self.epsilon}")
        if self.n_step < 1:
            raise ValueError(f"n_step must be at least 1, got {self.n_step}")


class TabularAgent:
    """Owns mutable Q tables (R, Σ P_a) and visit counts; robot i reads and writes row ``robot_table[i]``."""

    def __init__(self, policy: Policy, config: Phase2Config) -> None:
        self.template = policy
        self.config = config
        self.tables = policy.tables.astype(np.float64, copy=True)
        self.visits = (
            np.zeros(policy.tables.shape, np.uint64) if policy.visits is None else policy.visits.astype(np.uint64)
        )

    @property
    def discretization(self) -> Discretization:
        return self.template.discretization

    def cells(self, states: np.ndarray) -> np.ndarray:
        return self.template.discretization.cells(states)

    def act(self, robots: np.ndarray, cells: np.ndarray, rng: np.random.Generator, explore: bool) -> np.ndarray:
        """(N,) greedy actions on each robot's table; with ``explore`` a fraction ε is replaced by random ones."""
        actions = row_best(self.tables, self.template.rows(robots), cells)[1]
        return self.explore(actions, rng) if explore else actions

    def explore(
        self,
        greedy: np.ndarray,
        rng: np.random.Generator,
        guided: Callable[[np.ndarray], np.ndarray] | None = None,
        share: float = 0.0,
    ) -> np.ndarray:
        """``greedy`` (N,) actions with a fraction ε replaced by random ones (what ``act`` does with ``explore``).

        With ``guided``, which gives a guide's moves (:class:`sim.guide.Guide`) at (k,) indices into the N, a replaced
        action is the guided one with probability ``share`` and a uniform one otherwise; the guide is asked only for
        the actions it replaces.
        """
        n = greedy.size
        if guided is None or share <= 0:
            if self.config.epsilon <= 0:
                return greedy
            flip = rng.random(n) < self.config.epsilon
            return np.where(flip, rng.integers(0, N_ACTIONS, n), greedy)
        flip = rng.random(n) < self.config.epsilon
        take = rng.random(n) < share
        uniform = rng.integers(0, N_ACTIONS, n)
        out = np.where(flip, uniform, greedy)
        led = np.flatnonzero(flip & take)
        if led.size:
            out[led] = guided(led)
        return out

    def update(
        self,
        robots: np.ndarray,
        cell_sa: np.ndarray,
        next_cells: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
    ) -> None:
        """Eq. 1 for N tuples: ``cell_sa`` (N,) cell of (s, a), ``next_cells`` (N, L) cells of s′."""
        if robots.size == 0:
            return
        rows = self.template.rows(robots)
        size = self.tables.shape[1]
        targets = q_targets(row_best(self.tables, rows, next_cells)[0], rewards, dones, self.config.gamma)
        q_update(
            self.tables.reshape(-1),
            self.visits.reshape(-1),
            rows * size + cell_sa,
            targets,
            self.config.alpha,
            self.config.alpha_floor,
        )

    def returns(self, n_rows: int) -> NStepReturns | None:
        """The unfinished n-step targets of a learning trial of ``n_rows`` robots (arenas × robots); None with
        one-step targets, which :meth:`update` applies at once."""
        return None if self.config.n_step == 1 else NStepReturns(self, n_rows)

    def policy(self, **changes: object) -> Policy:
        """A snapshot of the current tables as an immutable policy."""
        return dataclasses.replace(
            self.template,
            tables=self.tables.astype(np.float32),
            visits=self.visits.copy(),
            **changes,  # type: ignore[arg-type]
        )


class NStepReturns:
    """A learning trial's unfinished n-step targets (:attr:`Phase2Config.n_step`): per robot of the trial (a row,
    arena · m + robot), the table cells of its last decisions and their rewards, until n of them are known.

    Usage (one per trial: a trial's end applies every target it holds)::

        returns = agent.returns(n_arenas * m)
        returns.update(trial_rows, robots, cell_sa, next_cells, rewards, dones, ends)   # instead of agent.update
    """

    def __init__(self, agent: TabularAgent, n_rows: int) -> None:
        self.agent = agent
        n = agent.config.n_step
        self._cells = np.zeros((n_rows, n), np.int64)
        self._rewards = np.zeros((n_rows, n), np.float64)
        self._length = np.zeros(n_rows, np.int64)

    def update(
        self,
        trial_rows: np.ndarray,
        robots: np.ndarray,
        cell_sa: np.ndarray,
        next_cells: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        ends: np.ndarray,
    ) -> None:
        """N tuples ending now: ``trial_rows`` (N,) their robots' rows in the trial, ``cell_sa`` (N,) the cell of
        (s, a), ``next_cells`` (N, L) the cells of s′; ``ends`` (N,) the robot's trial ends here (``dones``:
        terminally), so each of its held decisions gets its target, shorter than n. Every target completed now is
        applied to the tables (Eq. 1 with the n-step target)."""
        agent = self.agent
        if robots.size == 0:
            return
        rows = agent.template.rows(robots)
        size = agent.tables.shape[1]
        n = agent.config.n_step
        cells = np.empty(robots.size * n, np.int64)
        targets = np.empty(robots.size * n, np.float64)
        done = n_step_targets(
            np.asarray(trial_rows, np.int64),
            rows * size + np.asarray(cell_sa, np.int64),
            np.asarray(rewards, np.float64),
            row_best(agent.tables, rows, next_cells)[0].astype(np.float64),
            np.asarray(ends, bool),
            np.asarray(dones, bool),
            agent.config.gamma,
            self._cells,
            self._rewards,
            self._length,
            cells,
            targets,
        )
        q_update(
            agent.tables.reshape(-1),
            agent.visits.reshape(-1),
            cells[:done],
            targets[:done],
            agent.config.alpha,
            agent.config.alpha_floor,
        )
