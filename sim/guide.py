"""Exploration guided by a hand-made law: part of a learning trial's exploration takes the law's move.

A :class:`Guide` is part of a formulation's learning-trial rules (:class:`sim.formulation.TrialRules`), so it shapes
learning trials only; the learned policy acts on its tables alone::

    guide = Guide("force-6d-shared", explore=0.5, epsilon=0.5)
    actions = guide.actions(cfg, state)   # (E, m) the law's move of every robot, as an action of the formulation's set
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sim.config import ScenarioConfig
from sim.controllers import HAND_MADE, StateForceController
from sim.world import Observation, WorldState

if TYPE_CHECKING:
    from sim.trial import TrialState

GUIDES: dict[str, StateForceController] = {
    name: law for name, law in HAND_MADE.items() if isinstance(law, StateForceController)
}
"""The laws exploration may take moves from: the force laws on what the learned state holds (the nearest and the
furthest target in view, the nearest robot in view, and with ``force-6d-shared`` whether a teammate sees those
targets), so a guided robot moves on nothing its own state lacks."""

_NO_RNG = np.random.default_rng(0)
"""The guides draw nothing (a force law is deterministic); their interface asks for a generator."""


@dataclass(frozen=True, slots=True)
class Guide:
    """Exploration that takes a hand-made law's move part of the time [beyond the paper].

    Random exploration (phase 0) takes the law's move at a decision with probability ``explore`` and a uniform one
    otherwise; an ε-greedy learner that explores (phase 2) takes the law's move with probability ``epsilon`` and a
    uniform one otherwise. The law's move becomes the action of the formulation's set closest to it in direction.
    The tuples stay the robots' own, s, a, r, s′, and the tables learn from them as from any other exploration.
    Uniform moves alone rarely leave a target a teammate already watches to search for another, the behaviour that
    covers more targets; mixed with the law's moves, phase 1's cells and the tables meet it
    (docs/notebook.md, "2026-12-04: exploration guided by the force law").
    """

    law: str = "force-6d-shared"
    """The law, by name (:data:`GUIDES`)."""
    explore: float = 0.5
    """Share of phase 0's random decisions that take the law's move."""
    epsilon: float = 0.5
    """Share of phase 2's ε-explorations that take the law's move."""

    def __post_init__(self) -> None:
        if self.law not in GUIDES:
            raise ValueError(f"guide: unknown law {self.law!r} (known: {', '.join(GUIDES)})")
        for name, share in (("explore", self.explore), ("epsilon", self.epsilon)):
            if not 0.0 <= share <= 1.0:
                raise ValueError(f"guide {name} share must lie in [0, 1], got {share}")

    def actions(self, cfg: ScenarioConfig, state: TrialState, rows: np.ndarray | None = None) -> np.ndarray:
        """(E, m) the law's move of every robot now, as an action of the formulation's set (a robot the law pulls
        nowhere: its search heading's); given ``rows`` (k,) flat robot indices (arena · m + robot), (k,) the moves of
        those robots only. The law reads the state's view: a remembering state's remembered target pulls as a sensed
        one (:mod:`sim.recall`)."""
        world, view, heading = state.world, state.view, state.heading
        if rows is not None:
            world, view, heading = _only(world, view, heading, rows)
        velocity, _ = GUIDES[self.law].act(cfg, world, view, heading, _NO_RNG)
        moves = state.formulation.actions
        chosen = moves.closest(velocity, moves.frame(view, heading))
        return chosen if rows is None else chosen[0]


def _only(
    world: WorldState, view: Observation, heading: np.ndarray, rows: np.ndarray
) -> tuple[WorldState, Observation, np.ndarray]:
    """The robots ``rows`` laid out as one arena of k robots. A state law reads each robot's own sensing, memory,
    position and heading, never another robot's nor a target's position, so their moves there are their moves in
    their arenas: exploration asks the law only for the few robots that take its move, not for every robot."""

    def pick(a: np.ndarray) -> np.ndarray:
        return a.reshape(-1, *a.shape[2:])[rows][None]

    no_targets = np.zeros((1, 0, 2))
    alone = WorldState(pick(world.robot_pos), no_targets, no_targets, np.zeros((1, 0)), world.t)
    fields = ("features", "n_seen", "sees_robot", "shared", "n_only", "memory", "remembers")
    picked = {name: pick(getattr(view, name)) for name in fields if getattr(view, name) is not None}
    return alone, dataclasses.replace(view, covered=view.covered[:1], sighted=None, **picked), pick(heading)
