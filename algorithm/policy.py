"""A learned CMOMMT policy: per-action discretizations, per-robot Q tables, and how robots act on them.

Usage::

    policy = Policy(FORMULATIONS["paper"], discretization=disc, tables=q, robot_table=np.arange(10), ...)
    actions = policy.greedy(states, robots)            # (N,) action indices for states (N, d) of robots (N,)
    cautious = dataclasses.replace(policy, law_margin=0.3)   # a law set's readout that departs from "law" less
    evaluate(cfg, PolicyController(policy), trials=10, steps=1000)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from algorithm.discretization import Discretization
from algorithm.qtable import row_best
from sim import ScenarioConfig, evaluate
from sim.features import lost
from sim.formulation import Formulation
from sim.recall import Recall, forget_all, view_of
from sim.rollout import EvalResult, StepHook
from sim.world import Observation, WorldState

LostBehaviour = Literal["wander", "stay", "policy"]
ActionMode = Literal["fixed", "until_change"]


@dataclass(frozen=True, slots=True)
class Policy:
    """Everything needed to act: state definition, discretization, Q tables and the acting rules."""

    formulation: Formulation
    """What it was learned on: its state definition, what its action indices mean, and (provenance: acting does not
    read them) the reward and trial rules."""
    discretization: Discretization
    tables: np.ndarray
    """(R, Σ P_a) float32 Q tables; option 2 has one row per robot, option 1 and VQQL one row."""
    robot_table: np.ndarray
    """(m,) int64: the table row robot i uses."""
    action_steps: int = 5
    """Steps an action lasts (``fixed`` mode) [choice]."""
    action_mode: ActionMode = "fixed"
    """``fixed``: act every ``action_steps``; ``until_change``: keep the action until the discretized state
    changes, at most ``max_action_steps`` steps (VQQL) [paper]."""
    max_action_steps: int = 20
    """Cap of ``until_change`` actions [choice]."""
    lost_behaviour: LostBehaviour = "wander"
    """What a robot that sees no target does in test trials: keep its heading and reflect off the wall, stay
    motionless, or follow the policy on the masked state [choice]."""
    visits: np.ndarray | None = None
    """(R, Σ P_a) visit counts of the tables, when known."""
    version: int = 0
    """Policy version (distributed runs)."""
    method: str = ""
    """Name of the method that learned it, e.g. ``ennc-ql-collab-option2``."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Free-form provenance (seeds, configs) kept in the policy file header."""
    law_margin: float = 0.0
    """With a law action set: a robot takes another move than ``law`` (action 0) only where its value beats
    ``law``'s by more than this; 0: the plain argmax [beyond the paper: a cell's value of a departure averages over
    every state the cell holds, so it can beat the law's there while losing in most states where the argmax takes
    it; docs/concepts/saving.md]."""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.law_margin) and self.law_margin >= 0):
            raise ValueError(f"law_margin must be a finite number >= 0, got {self.law_margin}")
        if self.law_margin > 0 and self.formulation.actions.law is None:
            raise ValueError(f"law_margin needs a law action set, not {self.formulation.actions.name!r}")
        if self.formulation.dim != self.discretization.dim:
            raise ValueError("featurizer dimension and discretization dimension differ")
        if self.tables.ndim != 2 or self.tables.shape[1] != self.discretization.size:
            raise ValueError(f"tables must have shape (R, {self.discretization.size}), got {self.tables.shape}")
        if self.robot_table.min() < 0 or self.robot_table.max() >= self.tables.shape[0]:
            raise ValueError("robot_table names a table row that does not exist")
        if self.visits is not None and self.visits.shape != self.tables.shape:
            raise ValueError("visits must have the shape of tables")

    @property
    def n_robots(self) -> int:
        return int(self.robot_table.size)

    def rows(self, robots: np.ndarray) -> np.ndarray:
        return self.robot_table[np.asarray(robots) % self.robot_table.size]

    def greedy(self, states: np.ndarray, robots: np.ndarray, cells: np.ndarray | None = None) -> np.ndarray:
        """(N,) argmax_a Q_robot(s, a) for states (N, d) of robots (N,); with a ``law_margin``, action 0 (``law``)
        unless the best value beats its value by more than the margin."""
        cells = self.discretization.cells(states) if cells is None else cells
        rows = self.rows(robots)
        # One pass over the robots' rows in place: gathering each robot's whole row first copied the table once per
        # robot (N × Σ P_a, 75 MB a step for the learner's 200 test trials of 10 robots).
        best, action = row_best(self.tables, rows, cells)
        if self.law_margin == 0:
            return action
        law = self.tables[rows, cells[:, 0]]
        return np.where(best - law > self.law_margin, action, 0)

    def team(self) -> Policy:
        """The same policy with one table every robot uses: the rows merged cell by cell, each weighted by its visits
        (a cell no row visited keeps the rows' mean). Robots are alike, so each row is one robot's noisy estimate of
        the same values; the merge pools ten times the experience per cell [beyond the paper: the learner's merge
        across robots, after learning on option 2's per-robot tables]."""
        if self.tables.shape[0] == 1:
            return self
        tables = self.tables.astype(np.float64)
        if self.visits is None:
            merged, visits = tables.mean(axis=0), None
        else:
            weights = self.visits.astype(np.float64)
            seen = weights.sum(axis=0)
            weighted = (tables * weights).sum(axis=0) / np.maximum(seen, 1.0)
            merged = np.where(seen > 0, weighted, tables.mean(axis=0))
            visits = self.visits.sum(axis=0, keepdims=True)
        return dataclasses.replace(
            self,
            tables=merged[None].astype(np.float32),
            robot_table=np.zeros_like(self.robot_table),
            visits=visits,
        )

    def prototypes_by_action(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Per action: its prototypes in the standardized space the cells are measured in (p_a, d), and each one's
        Q value averaged over the tables (p_a,); what the monitor and the policy figure draw."""
        disc = self.discretization
        scale = np.ones(disc.dim) if disc.scale is None else disc.scale
        q = self.tables.mean(axis=0)
        bounds = list(zip(disc.offsets[:-1], disc.offsets[1:], strict=True))
        return [disc.prototypes[lo:hi] / scale for lo, hi in bounds], [q[lo:hi] for lo, hi in bounds]


TALLY = 4
"""The counts of :attr:`PolicyController.tally`."""


@dataclass(frozen=True, slots=True)
class OffLaw:
    """How often a law action set's policy departed from the move law, over its robots' decisions."""

    pct: float
    """Decisions that took another move than ``law`` (%)."""
    shared_pct: float
    """Decisions taken where a teammate also watched one of the robot's targets (% of all decisions)."""
    shared_off_pct: float
    """Of those, the ones that took another move than ``law`` (%): the departures that can be cooperation (handing a
    target over, leaving a shared one to search)."""

    @classmethod
    def of(cls, tally: np.ndarray) -> OffLaw:
        decisions, off, shared, shared_off = (int(v) for v in tally)
        return cls(
            100.0 * off / max(decisions, 1), 100.0 * shared / max(decisions, 1), 100.0 * shared_off / max(shared, 1)
        )


def evaluate_off_law(
    cfg: ScenarioConfig, policy: Policy, trials: int, steps: int, seed: int, on_step: StepHook | None = None
) -> tuple[EvalResult, OffLaw | None]:
    """``sim.evaluate`` of ``policy`` on those trials, and with a law action set how often its robots' decisions took
    another move than ``law`` (None for other sets): how far the learned policy departs from the hand-made law it
    holds as one of its moves, and where."""
    if policy.formulation.actions.law is None:
        return evaluate(cfg, PolicyController(policy), trials, steps, seed=seed, on_step=on_step), None
    controller = PolicyController(policy, tally=np.zeros(TALLY, np.int64))
    result = evaluate(cfg, controller, trials, steps, seed=seed, on_step=on_step)
    return result, controller.off_law()


@dataclass(frozen=True, slots=True)
class _Memory:
    action: np.ndarray  # (E, m) int64 current action index
    heading: np.ndarray  # (E, m, 2) unit heading of wandering robots
    held: np.ndarray  # (E, m) int64 steps the current action has lasted
    cell: np.ndarray  # (E, m) int64 cell of the state the action started in (until_change mode)
    frame: np.ndarray  # (E, m, 2, 2) float64 the frame the current action was chosen in (rows: x, y axes)
    recall: Recall | None  # every robot's last sighting, for a state that remembers (sim.recall)


@dataclass(frozen=True, slots=True)
class PolicyController:
    """Drives every robot of a scenario with a learned :class:`Policy` (greedy), for test trials."""

    policy: Policy
    name: str = "policy"
    tally: np.ndarray | None = None
    """(TALLY,) int64 added to in place: the robots' decisions, those that took another move than action 0 (``law``
    for a law action set), those taken where a teammate also watched one of the robot's targets, and those of them
    off action 0; None: not counted."""

    def off_law_pct(self) -> float | None:
        """The percentage of the counted decisions that took another move than action 0; None when not counted."""
        return None if self.tally is None else OffLaw.of(self.tally).pct

    def off_law(self) -> OffLaw | None:
        """The counted decisions' departures from action 0, overall and where targets were shared."""
        return None if self.tally is None else OffLaw.of(self.tally)

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> _Memory:
        shape = (world.n_arenas, cfg.n_robots)
        angle = rng.uniform(0.0, 2.0 * np.pi, shape)
        return _Memory(
            action=np.zeros(shape, np.int64),
            heading=np.stack([np.cos(angle), np.sin(angle)], axis=-1),
            held=np.full(shape, 1 << 30, np.int64),
            cell=np.full(shape, -1, np.int64),
            frame=np.broadcast_to(np.eye(2), (*shape, 2, 2)),
            recall=forget_all(cfg, shape) if self.policy.formulation.featurizer.recalls else None,
        )

    def act(
        self, cfg: ScenarioConfig, world: WorldState, obs: Observation, memory: _Memory, rng: np.random.Generator
    ) -> tuple[np.ndarray, _Memory]:
        p = self.policy
        n_arenas, m = memory.action.shape
        view, recall = view_of(cfg, world, obs, memory.recall)
        states = p.formulation.featurizer.compute(cfg, view).reshape(n_arenas * m, -1)
        robots = np.tile(np.arange(m), n_arenas)
        held = memory.held
        if p.action_mode == "fixed":
            decide = np.broadcast_to(world.t % p.action_steps == 0, (n_arenas, m))
            cells = p.discretization.cells(states) if decide.any() else None
            cell_now = memory.cell
        else:
            cells = p.discretization.cells(states)
            cell_now = cells[np.arange(n_arenas * m), memory.action.reshape(-1)].reshape(n_arenas, m)
            decide = (cell_now != memory.cell) | (held >= p.max_action_steps)
        action = memory.action
        cell = memory.cell
        moves = p.formulation.actions
        frame = memory.frame
        # The heading turns before the robots decide: a search set's move "law" is the law's own move of this step.
        heading = moves.steer(cfg, world, view, memory.heading)
        if cells is not None and decide.any():
            chosen = p.greedy(states, robots, cells).reshape(n_arenas, m)
            if self.tally is not None:
                off = decide & (chosen != 0)
                shared = decide & (obs.n_seen > obs.n_only)
                self.tally[:] += (int(decide.sum()), int(off.sum()), int(shared.sum()), int((shared & off).sum()))
            action = np.where(decide, chosen, action)
            start_cell = cells[np.arange(n_arenas * m), action.reshape(-1)].reshape(n_arenas, m)
            cell = np.where(decide, start_cell, cell_now)
            if moves.relative:
                frame = np.where(decide[..., None, None], moves.frame(view, heading), frame)
        held = np.where(decide, 1, held + 1)
        velocity = moves.velocity(cfg, action, frame)
        if p.lost_behaviour != "policy":
            gone = lost(view)[..., None]
            search = cfg.robot_speed * heading if p.lost_behaviour == "wander" else 0.0
            velocity = np.where(gone, search, velocity)
        return velocity, _Memory(action=action, heading=heading, held=held, cell=cell, frame=frame, recall=recall)
