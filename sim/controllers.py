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
from sim.config import ForceLawConfig, ScenarioConfig
from sim.recall import Recall, forget_all, recall
from sim.world import Observation, WorldState

COMPASS_NAMES = ("N", "NE", "E", "SE", "S", "SW", "W", "NW")
"""The eight discrete actions [paper], index order used by every policy and table."""
_ANGLES = np.pi / 2 - np.arange(8) * np.pi / 4
COMPASS = np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=-1)
"""(8, 2) unit vectors, north = +y, clockwise."""
N_ACTIONS = len(COMPASS_NAMES)

PUBLIC_FORCE_LAW = ForceLawConfig()
"""A-CMOMMT's parameters as the public code gives them, scaled to this arena, untuned here (teammate-observed
weight 0.25, do1 20, do2 40, do4 180, dr1 62.5, dr2 100, prediction 60 steps) [public]: ``a-cmommt-public``."""
ACMOMMT_LAW = ForceLawConfig(
    do1=10.0, do2=150.0, do4=1000.0, dr1=0.0, dr2=50.0, shared_target_weight=0.0, predict_steps=240
)
"""A-CMOMMT's parameters chosen by ``scripts/tune_references.py`` on training seeds 100–103 (50 trials each), never on
the reported test trials [choice: tuned here, the robot repulsion on the script's finer grid; docs/notebook.md,
"2026-12-02: the honest A-CMOMMT, tuned on training trials"]: ``a-cmommt``. The oracle keeps the public law: with this
do4 it would read the true position of nearly every target in the arena."""
STATE_FORCE_LAW = ForceLawConfig(do1=10.0, do2=150.0, do4=ACMOMMT_LAW.do4, shared_target_weight=0.0)
"""The force law on the learned state's information (``force-6d-shared``), tuned by the same script on the same
training seeds over the parameters that act on sensed targets, on its first grids [choice: the finer robot-repulsion
grid picks dr1 0, dr2 50 (+0.25 on the training trials); kept, since this law is also the learned moves' (``law``
action sets) and the exploration guide's, and a policy file names its action set, not the law's parameters;
the learning on the finer law measured level: docs/notebook.md, "2026-12-06: the crowding measured from four sides,
and a finer grid for the reference"]. The band beyond sensing range acts only on a remembered target (a
guide reading a remembering state's view, :mod:`sim.guide`), and takes the tuned ``a-cmommt``'s reach."""


def compass_velocity(cfg: ScenarioConfig, actions: np.ndarray) -> np.ndarray:
    """(…, 2) full-speed displacement for compass action indices (…)."""
    return cfg.robot_speed * COMPASS[actions]


def random_headings(cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> np.ndarray:
    """(E, m, 2) unit headings at uniform angles: the first heading of a force-law robot."""
    angle = rng.uniform(0.0, 2.0 * np.pi, (world.n_arenas, cfg.n_robots))
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


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
class Tracks:
    """A force-law robot's memory: its heading and its own last sighting of every target."""

    heading: np.ndarray
    """(E, m, 2) float64 unit vectors, kept when no force acts."""
    position: np.ndarray
    """(E, m, n, 2) float64: robot i's last observed position of target j."""
    velocity: np.ndarray
    """(E, m, n, 2) float64: the target's displacement per step estimated from robot i's sightings."""
    age: np.ndarray
    """(E, m, n) int64: steps since robot i last observed target j (``NEVER_SEEN`` if it never did)."""


@dataclass(frozen=True, slots=True)
class ForceController:
    """Weighted attraction to targets and repulsion from robots, moving at full speed [paper; shape: public].

    ``cooperative=True`` is A-CMOMMT: a target that another robot also observes is down-weighted (the teammates'
    reports A-CMOMMT assumes) and robots within ``dr2`` repel. ``cooperative=False`` is the *local* controller:
    every target weighs 1 and robots ignore each other [choice: the spec's "all weights 1 (no cooperation)"].
    In the (do3, do4] band a robot is pulled only by what it can know [Parker 2002's *predictive tracking* range]:
    its own sightings predicted forward (``ForceLawConfig.predict_steps``) and, cooperative, targets teammates report
    (``reported_weight``). With no force the heading is kept (reflected at the wall) [choice].

    ``oracle=True`` is the law as first written here: every target within do4 pulls at its TRUE position, sensed or
    not, which no robot can know (``a-cmommt-oracle``: kept as a labelled reference, never as the baseline).
    """

    cooperative: bool = True
    name: str = "a-cmommt"
    oracle: bool = False
    law: ForceLawConfig = ACMOMMT_LAW

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> Tracks | np.ndarray:
        heading = random_headings(cfg, world, rng)
        if self.oracle:
            return heading
        shape = (world.n_arenas, cfg.n_robots, cfg.n_targets)
        return Tracks(
            heading=heading,
            position=np.zeros((*shape, 2)),
            velocity=np.zeros((*shape, 2)),
            age=np.full(shape, _kernels.NEVER_SEEN, np.int64),
        )

    def act(
        self,
        cfg: ScenarioConfig,
        world: WorldState,
        obs: Observation,
        memory: Tracks | np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, Tracks | np.ndarray]:
        f = self.law
        heading = np.empty_like(world.robot_pos)
        if isinstance(memory, np.ndarray):
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
        tracks = Tracks(
            heading=heading,
            position=np.empty_like(memory.position),
            velocity=np.empty_like(memory.velocity),
            age=np.empty_like(memory.age),
        )
        _kernels.tracked_force_heading(
            world.robot_pos,
            world.target_pos,
            memory.heading,
            memory.position,
            memory.velocity,
            memory.age,
            f.do1,
            f.do2,
            f.do3,
            f.do4,
            f.dr1,
            f.dr2,
            cfg.sensing_range,
            f.shared_target_weight,
            self.cooperative,
            f.predict_steps,
            f.reported_weight,
            cfg.arena_radius,
            tracks.heading,
            tracks.position,
            tracks.velocity,
            tracks.age,
        )
        return cfg.robot_speed * heading, tracks


@dataclass(frozen=True, slots=True)
class StateForceController:
    """A-CMOMMT's force law fed only what the ``collab6d`` state holds: the nearest and the furthest target in view and
    the nearest robot in view, read from the observation's features [choice: a state-limited reference, so that a
    learned policy is shown beside what its own state allows a hand-made law].

    ``shared=True`` adds, for those two targets, whether another robot observes them, and weighs such a target
    ``shared_target_weight`` as A-CMOMMT does: the communication A-CMOMMT assumes, which the 6-D state lacks. Unlike
    A-CMOMMT it sees no target beyond sensing range and no robot but the nearest. With no force the heading is kept
    and reflected off the wall, as A-CMOMMT's is.
    """

    shared: bool = False
    name: str = "force-6d"
    law: ForceLawConfig = PUBLIC_FORCE_LAW

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> np.ndarray:
        return random_headings(cfg, world, rng)

    def act(
        self,
        cfg: ScenarioConfig,
        world: WorldState,
        obs: Observation,
        memory: np.ndarray,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, np.ndarray]:
        # With one target in view the nearest and the furthest are the same target: it pulls once. A remembering
        # state's view: the remembered target of a robot that also sees one pulls as A-CMOMMT's predictions do (beyond
        # the sensing range, in the (do3, do4] band).
        f = self.law
        shape = obs.n_seen.shape
        recalled, remembers = np.zeros((*shape, 2)), np.zeros(shape, bool)
        if obs.remembers is not None and obs.memory is not None:
            recalled, remembers = np.asarray(obs.memory, np.float64), obs.remembers
        force = np.empty((*shape, 2))
        _kernels.state_forces(
            obs.features,
            obs.n_seen,
            obs.sees_robot,
            obs.shared,
            recalled,
            remembers,
            np.array([f.do1, f.do2, f.do3, f.do4, f.dr1, f.dr2, f.shared_target_weight if self.shared else 1.0]),
            force,
        )
        norm = np.linalg.norm(force, axis=-1, keepdims=True)
        heading = np.where(norm > 1e-12, force / np.maximum(norm, 1e-300), wander(cfg, world, memory))
        return cfg.robot_speed * heading, heading


@dataclass(frozen=True, slots=True)
class RecallForceController:
    """A law on a remembering state's information: ``law`` (a :class:`StateForceController`) fed the view of
    :func:`sim.recall.recall`, in which a robot's remembered target (one it lost, predicted from its own sightings,
    that no teammate sees now) pulls from beyond the sensing range [choice: the state-limited reference of the
    ``frame11d-recall`` state, as ``force-6d-shared`` is of ``frame9d``; its memory's reach and horizon are the
    state's own, do4 1000 (the tuned A-CMOMMT's) and ``recall_steps``, not tuned again]."""

    name: str = "force-recall"
    law: StateForceController = StateForceController(shared=True, name="force-6d-shared", law=STATE_FORCE_LAW)

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> tuple[np.ndarray, Recall]:
        return self.law.init(cfg, world, rng), forget_all(cfg, (world.n_arenas, cfg.n_robots))

    def act(
        self,
        cfg: ScenarioConfig,
        world: WorldState,
        obs: Observation,
        memory: tuple[np.ndarray, Recall],
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, tuple[np.ndarray, Recall]]:
        heading, tracks = memory
        view, tracks = recall(cfg, world, obs, tracks)
        velocity, heading = self.law.act(cfg, world, view, heading, rng)
        return velocity, (heading, tracks)


HAND_MADE: dict[str, Controller] = {
    "random": RandomController(),
    "local": ForceController(cooperative=False, name="local", law=PUBLIC_FORCE_LAW),
    "a-cmommt": ForceController(cooperative=True, name="a-cmommt"),
    "a-cmommt-public": ForceController(cooperative=True, name="a-cmommt-public", law=PUBLIC_FORCE_LAW),
    "force-6d": StateForceController(shared=False, name="force-6d"),
    "force-6d-shared": StateForceController(shared=True, name="force-6d-shared", law=STATE_FORCE_LAW),
    "force-recall": RecallForceController(),
}
"""The hand-made controllers a learned policy is compared with, by their CLI names, each on what its robots can sense
or be told: the paper's baselines (A-CMOMMT tuned here, the public code's untuned A-CMOMMT, local), and the
state-limited references (A-CMOMMT's force law on what the learned ``collab6d`` state holds, without and with the
shared-observation flags, the latter tuned, and that law on what ``frame11d-recall`` holds as well)."""
ORACLES: dict[str, Controller] = {
    "a-cmommt-oracle": ForceController(cooperative=True, name="a-cmommt-oracle", oracle=True, law=PUBLIC_FORCE_LAW),
}
"""References that read what no robot senses (true target positions), labelled as such: never a rival, and never in
a listing of :data:`HAND_MADE`."""
CONTROLLERS: dict[str, Controller] = {**HAND_MADE, **ORACLES}
"""Every controller by name, for a caller that names one (``eval``, ``reproduce``, ``ablate``'s references)."""


def wander(cfg: ScenarioConfig, world: WorldState, heading: np.ndarray) -> np.ndarray:
    """(E, m, 2) unit headings kept as they are but reflected off the wall when pointing out of the disk."""
    out = np.empty(world.robot_pos.shape)
    _kernels.wander(world.robot_pos, np.asarray(heading, np.float64), cfg.arena_radius, out)
    return out
