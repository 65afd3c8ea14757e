"""Hand-made controllers, vectorized over arenas and robots.

A controller is a pair of pure functions held by a small object::

    memory = controller.init(cfg, world, rng)
    velocity, memory = controller.act(cfg, world, obs, memory, rng)   # velocity: (E, m, 2) displacement

``memory`` is whatever the controller carries between steps (a held compass action, a heading); it is returned
anew, never modified in place.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from sim import _kernels
from sim.config import ScenarioConfig
from sim.world import Observation, WorldState

COMPASS_NAMES = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")
"""The eight discrete actions [paper], index order used by every policy and table."""
_ANGLES = np.pi / 2 - np.arange(8) * np.pi / 4
COMPASS = np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=-1)
"""(8, 2) unit vectors, north = +y, clockwise."""
N_ACTIONS = len(COMPASS_NAMES)


def compass_velocity(cfg: ScenarioConfig, actions: np.ndarray) -> np.ndarray:
    """(…, 2) full-speed displacement for compass action indices (…)."""
    return cfg.robot_speed * COMPASS[actions]


class Controller(Protocol):
    """What :func:`sim.rollout.evaluate` drives."""

    @property
    def name(self) -> str: ...

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> Any: ...

    def act(
        self, cfg: ScenarioConfig, world: WorldState, obs: Observation, memory: Any, rng: np.random.Generator
    ) -> tuple[np.ndarray, Any]: ...


@dataclass(frozen=True, slots=True)
class RandomController:
    """One of the 8 compass moves, drawn uniformly and held for ``action_steps`` steps [choice]."""

    name: str = "random"

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> np.ndarray:
        return rng.integers(0, N_ACTIONS, (world.n_arenas, cfg.n_robots))

    def act(
        self,
        cfg: ScenarioConfig,
        world: WorldState,
        obs: Observation,
        memory: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        actions = memory
        if world.t % cfg.action_steps == 0 and world.t > 0:
            actions = rng.integers(0, N_ACTIONS, actions.shape)
        return compass_velocity(cfg, actions), actions


@dataclass(frozen=True, slots=True)
class ForceController:
    """Weighted attraction to targets and repulsion from robots, moving at full speed [paper; shape: public].

    ``cooperative=True`` is A-CMOMMT: targets that another robot already observes are down-weighted and nearby
    robots repel. ``cooperative=False`` is the *local* controller: every target weighs 1 and robots ignore each
    other [choice: the spec's "all weights 1 (no cooperation)"]. With no force the heading is kept (reflected at
    the wall) [choice].
    """

    cooperative: bool = True
    name: str = "a-cmommt"

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> np.ndarray:
        angle = rng.uniform(0.0, 2.0 * np.pi, (world.n_arenas, cfg.n_robots))
        return np.stack([np.cos(angle), np.sin(angle)], axis=-1)

    def act(
        self,
        cfg: ScenarioConfig,
        world: WorldState,
        obs: Observation,
        memory: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        f = cfg.force
        heading = np.empty_like(world.robot_pos)
        _kernels.force_heading(
            world.robot_pos,
            world.target_pos,
            memory,
            f.do1,
            f.do2,
            f.do3,
            f.do4,
            f.dr1,
            f.dr2,
            cfg.sensing_range,
            f.shared_target_weight if self.cooperative else 1.0,
            self.cooperative,
            cfg.arena_radius,
            heading,
        )
        return cfg.robot_speed * heading, heading


HAND_MADE: dict[str, Controller] = {
    "random": RandomController(),
    "local": ForceController(cooperative=False, name="local"),
    "a-cmommt": ForceController(cooperative=True, name="a-cmommt"),
}
"""The paper's hand-made baselines by their CLI names."""


def wander(cfg: ScenarioConfig, world: WorldState, heading: np.ndarray) -> np.ndarray:
    """(E, m, 2) unit headings kept as they are but reflected off the wall when pointing out of the disk."""
    pos = world.robot_pos
    r = np.linalg.norm(pos, axis=-1, keepdims=True)
    normal = pos / np.maximum(r, 1e-300)
    outward = np.einsum("emk,emk->em", heading, normal)[..., None]
    at_wall = (r >= cfg.arena_radius - 1e-9) & (outward > 0)
    return np.where(at_wall, heading - 2.0 * outward * normal, heading)
