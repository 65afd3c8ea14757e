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
from algorithm.qtable import q_targets, q_update, row_best
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

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must lie in (0, 1], got {self.alpha}")
        if self.alpha_floor is not None and not 0.0 < self.alpha_floor <= self.alpha:
            raise ValueError(f"alpha_floor must lie in (0, alpha], got {self.alpha_floor}")
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"gamma must lie in [0, 1), got {self.gamma}")
        if not 0.0 <= self.epsilon <= 1.0:
            raise ValueError(f"epsilon must lie in [0, 1], got {self.epsilon}")


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
        targets = q_targets(row_best(self.tables, rows, next_cells)[0], rewards, dones, self.config.gamma)
        size = self.tables.shape[1]
        q_update(
            self.tables.reshape(-1),
            self.visits.reshape(-1),
            rows * size + cell_sa,
            targets,
            self.config.alpha,
            self.config.alpha_floor,
        )

    def policy(self, **changes: object) -> Policy:
        """A snapshot of the current tables as an immutable policy."""
        return dataclasses.replace(
            self.template,
            tables=self.tables.astype(np.float32),
            visits=self.visits.copy(),
            **changes,  # type: ignore[arg-type]
        )
