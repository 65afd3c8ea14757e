"""The CMOMMT world as pure functions over a batch of independent arenas.

Call sequence::

    rng = np.random.default_rng(seed)
    state = reset(cfg, n_arenas=E, rng=rng)
    obs = sense(cfg, state, rng)                   # what every robot perceives now
    state = step(cfg, state, velocity, rng)        # velocity (E, m, 2): displacement of each robot this step

``step`` and ``sense`` never modify their inputs; all randomness comes from the ``rng`` passed in, so a run is
reproduced exactly from its seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import _kernels
from sim.config import ScenarioConfig


@dataclass(frozen=True, slots=True)
class WorldState:
    """Positions and velocities of every robot and target, for E arenas."""

    robot_pos: np.ndarray
    """(E, m, 2) float64, arena units; always inside the disk."""
    target_pos: np.ndarray
    """(E, n, 2) float64, arena units; always inside the disk."""
    target_vel: np.ndarray
    """(E, n, 2) float64, arena units per step."""
    target_speed: np.ndarray
    """(E, n) float64, fixed per target."""
    t: int = 0
    """Steps taken since reset."""

    @property
    def n_arenas(self) -> int:
        return int(self.robot_pos.shape[0])


@dataclass(frozen=True, slots=True)
class Observation:
    """What the robots perceive at one instant, and the ground truth needed for rewards and metric A."""

    features: np.ndarray
    """(E, m, 6) float32: (dx, dy) to the nearest target in view, to the furthest target in view, and to the
    nearest robot in view, each masked with (mask, mask) when nothing is in view [paper]."""
    n_seen: np.ndarray
    """(E, m) int32: Σ_j b_ij, the number of targets robot i observes."""
    sees_robot: np.ndarray
    """(E, m) bool: another robot is within sensing range."""
    covered: np.ndarray
    """(E,) int32: Σ_j g(B, j), the number of targets observed by at least one robot."""
    shared: np.ndarray
    """(E, m, 2) bool: another robot also observes the nearest / the furthest target in view (False when none is in
    view): the communication A-CMOMMT assumes [paper §3]."""
    n_only: np.ndarray
    """(E, m) int32: targets this robot observes and no other does, i.e. G(z) − G(z without robot i) of metric A's
    summand, the robot's difference [Agogino & Tumer]."""
    memory: np.ndarray | None = None
    """(E, m, 2) float32 or None: the offset to the robot's remembered target where it also sees a target (0 where
    ``remembers`` is False); set only in the view of a state that remembers (:func:`sim.recall.recall`, where a robot
    that sees no target reads its remembered one as its nearest), None as sensed."""
    remembers: np.ndarray | None = None
    """(E, m) bool or None: ``memory`` holds a remembered target; None as sensed."""
    sighted: np.ndarray | None = None
    """(E, m, n) bool or None: robot i has target j within sensing range (true distance), as :func:`sense` found it,
    so that the tracks (:mod:`sim.recall`) need not measure again; None in an observation made elsewhere."""


def uniform_in_disk(rng: np.random.Generator, radius: float, shape: tuple[int, ...]) -> np.ndarray:
    """Points uniformly distributed in the disk, shape ``shape + (2,)``."""
    r = radius * np.sqrt(rng.random(shape))
    theta = rng.uniform(0.0, 2.0 * np.pi, shape)
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=-1)


MAX_ARENAS = 100_000
"""The most arenas a command simulates side by side (eval's trials, an actor's arenas, a learner's test trials): each
holds about 12 KB of world, observation and feature arrays (eval of a policy file: 20 000 trials take 220 MB more
than 1 000), so 100 000 take about 1.2 GB; far more would end in a MemoryError or in swap."""


def reset(cfg: ScenarioConfig, n_arenas: int, rng: np.random.Generator) -> WorldState:
    """E fresh arenas: robots and targets uniform in the disk, target headings uniform [choice]."""
    if n_arenas < 1:
        raise ValueError(f"n_arenas must be at least 1, got {n_arenas}")
    m, n = cfg.n_robots, cfg.n_targets
    robot_pos = uniform_in_disk(rng, cfg.arena_radius, (n_arenas, m))
    target_pos = uniform_in_disk(rng, cfg.arena_radius, (n_arenas, n))
    speed = rng.uniform(0.0, cfg.target_speed_frac * cfg.robot_speed, (n_arenas, n))
    angle = rng.uniform(0.0, 2.0 * np.pi, (n_arenas, n))
    vel = np.stack([speed * np.cos(angle), speed * np.sin(angle)], axis=-1)
    return WorldState(robot_pos=robot_pos, target_pos=target_pos, target_vel=vel, target_speed=speed)


_NO_NOISE = np.zeros((0, 0, 0, 2))


def sense(cfg: ScenarioConfig, state: WorldState, rng: np.random.Generator | None = None) -> Observation:
    """Every robot's observation; ``rng`` is needed only when the scenario has sensor noise."""
    n_arenas, m, n = state.n_arenas, cfg.n_robots, cfg.n_targets
    noise_t = noise_r = _NO_NOISE
    if cfg.sensor_noise_std > 0.0:
        if rng is None:
            raise ValueError("a scenario with sensor noise needs an rng to sense")
        noise_t = rng.normal(0.0, cfg.sensor_noise_std, (n_arenas, m, n, 2))
        noise_r = rng.normal(0.0, cfg.sensor_noise_std, (n_arenas, m, m, 2))
    features = np.empty((n_arenas, m, 6), dtype=np.float32)
    n_seen = np.empty((n_arenas, m), dtype=np.int32)
    sees_robot = np.empty((n_arenas, m), dtype=np.bool_)
    covered = np.empty(n_arenas, dtype=np.int32)
    shared = np.empty((n_arenas, m, 2), dtype=np.bool_)
    n_only = np.empty((n_arenas, m), dtype=np.int32)
    sighted = np.empty((n_arenas, m, n), dtype=np.bool_)
    _kernels.sense(
        state.robot_pos,
        state.target_pos,
        cfg.sensing_range,
        cfg.mask_value,
        noise_t,
        noise_r,
        features,
        n_seen,
        sees_robot,
        covered,
        shared,
        n_only,
        sighted,
    )
    return Observation(
        features=features,
        n_seen=n_seen,
        sees_robot=sees_robot,
        covered=covered,
        shared=shared,
        n_only=n_only,
        sighted=sighted,
    )


def step(cfg: ScenarioConfig, state: WorldState, velocity: np.ndarray, rng: np.random.Generator) -> WorldState:
    """Advance every arena by one step.

    ``velocity`` (E, m, 2) is each robot's displacement; its length is clipped to ``robot_speed``. Robots are
    projected back onto the disk; targets turn with probability ``target_turn_prob`` and reflect off the wall.
    """
    n_arenas, m, n = state.n_arenas, cfg.n_robots, cfg.n_targets
    velocity = np.asarray(velocity, dtype=np.float64)
    if velocity.shape != (n_arenas, m, 2):
        raise ValueError(f"velocity must have shape {(n_arenas, m, 2)}, got {velocity.shape}")
    speed = np.sqrt(np.einsum("emk,emk->em", velocity, velocity))
    too_fast = speed > cfg.robot_speed * (1.0 + 1e-9)
    if too_fast.any():
        velocity = velocity * np.where(too_fast, cfg.robot_speed / np.maximum(speed, 1e-300), 1.0)[..., None]
    turn = rng.random((n_arenas, n)) < cfg.target_turn_prob
    new_angle = rng.uniform(0.0, 2.0 * np.pi, (n_arenas, n))
    robot_pos = np.empty_like(state.robot_pos)
    target_pos = np.empty_like(state.target_pos)
    target_vel = np.empty_like(state.target_vel)
    _kernels.move(
        state.robot_pos,
        velocity,
        state.target_pos,
        state.target_vel,
        state.target_speed,
        turn,
        new_angle,
        cfg.arena_radius,
        robot_pos,
        target_pos,
        target_vel,
    )
    return WorldState(
        robot_pos=robot_pos,
        target_pos=target_pos,
        target_vel=target_vel,
        target_speed=state.target_speed,
        t=state.t + 1,
    )


def place_near_targets(
    cfg: ScenarioConfig, state: WorldState, robots: np.ndarray, rng: np.random.Generator
) -> WorldState:
    """Move ``robots`` (bool (E, m)) to uniform points within sensing range of a random target of their arena.

    Learning trials start this way so that the learning robot begins with something in view [choice].
    """
    robots = np.asarray(robots, dtype=bool)
    if robots.shape != (state.n_arenas, cfg.n_robots):
        raise ValueError(f"robots must have shape {(state.n_arenas, cfg.n_robots)}, got {robots.shape}")
    arena, robot = np.nonzero(robots)
    target = rng.integers(0, cfg.n_targets, arena.size)
    offset = uniform_in_disk(rng, 0.9 * cfg.sensing_range, (arena.size,))
    pos = state.target_pos[arena, target] + offset
    radius = np.linalg.norm(pos, axis=-1, keepdims=True)
    pos = np.where(radius > cfg.arena_radius, pos * (cfg.arena_radius / np.maximum(radius, 1e-300)), pos)
    robot_pos = state.robot_pos.copy()
    robot_pos[arena, robot] = pos
    return WorldState(
        robot_pos=robot_pos,
        target_pos=state.target_pos,
        target_vel=state.target_vel,
        target_speed=state.target_speed,
        t=state.t,
    )
