"""Shared test helpers, imported by the tests that need them instead of from each other: a tiny learning budget,
a hand-built arena, a random policy, and a learner run that ends on an outcome."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from actors.actor import RobotActor
from actors.config import ActorConfig
from actors.wiring import connect as connect_actor
from algorithm.discretization import Discretization
from algorithm.experiments import Budget
from algorithm.phase1 import Phase1Config
from algorithm.policy import Policy
from learner.report import LearnerReport
from learner.service import LearnerService
from learner.wiring import connect as connect_learner
from protocol import Transport
from sim import FORMULATIONS, Formulation, ScenarioConfig, TrialState, WorldState, sense
from sim.recall import forget_all, view_of

TINY = Budget(
    arenas=24,
    explore_trials=1,
    phase2_trials=2,
    phase1=Phase1Config(max_iterations=1, n_cycles=25, max_patterns=1500),
    codebook_patterns=1500,
    test_trials=2,
    test_steps=120,
    law_margin_trials=2,
)
"""A learning process in a second or three: poor policies, but policies the project wrote."""


def situation(
    cfg: ScenarioConfig,
    robots: list[tuple[float, float]],
    targets: list[tuple[float, float]],
    learner: list[bool],
    target_vel: list[tuple[float, float]] | None = None,
    heading: list[tuple[float, float]] | None = None,
    formulation: Formulation = FORMULATIONS["paper"],
) -> TrialState:
    """One arena at the start of a trial under ``formulation`` (the paper's unless given), robots and targets where
    given (targets still unless ``target_vel``)."""
    vel = np.zeros((1, len(targets), 2)) if target_vel is None else np.array([target_vel], dtype=np.float64)
    world = WorldState(
        robot_pos=np.array([robots], dtype=np.float64),
        target_pos=np.array([targets], dtype=np.float64),
        target_vel=vel,
        target_speed=np.linalg.norm(vel, axis=-1),
    )
    obs = sense(cfg, world)
    m = len(robots)
    memory = forget_all(cfg, (1, m)) if formulation.featurizer.recalls else None
    view, memory = view_of(cfg, world, obs, memory)
    features = formulation.featurizer.compute(cfg, view)
    mask = np.array([learner])
    frame = np.array(formulation.actions.frame(view), dtype=np.float64)
    return TrialState(
        world=world,
        obs=obs,
        view=view,
        recall=memory,
        formulation=formulation,
        features=features,
        action=np.zeros((1, m), np.int64),
        held=np.zeros((1, m), np.int64),
        frame=frame,
        move=formulation.actions.velocity(cfg, np.zeros((1, m), np.int64), frame),
        start_features=features,
        learner=mask,
        active=mask.copy(),
        heading=np.array([heading or [(1.0, 0.0)] * m], dtype=np.float64),
        earned=np.zeros((1, m), np.float32),
    )


def make_policy(rng: np.random.Generator, robots: int = 10, rows: int = 10) -> Policy:
    protos = [rng.normal(0, 100, (int(rng.integers(1, 6)), 6)) for _ in range(8)]
    labels = [rng.normal(size=len(p)) for p in protos]
    disc = Discretization.from_per_action(protos, labels, scale=np.full(6, 50.0, np.float32))
    return Policy(
        formulation=FORMULATIONS["paper"],
        discretization=disc,
        tables=rng.normal(size=(rows, disc.size)).astype(np.float32),
        robot_table=np.arange(robots) % rows,
        visits=rng.integers(0, 100, (rows, disc.size)).astype(np.uint64),
        version=7,
        method="ennc-ql-collab-option2",
        meta={"seed": 3},
    )


def run_until(service: LearnerService, condition: Callable[[], bool]) -> LearnerReport:
    """``service.run`` until ``condition()`` holds (or its duration ends): a loaded CI machine may need most of
    the time for phase 1, so the tests end on the outcome, not on the clock."""
    done = threading.Event()

    def watch() -> None:
        while not done.is_set() and not condition():
            time.sleep(0.05)
        done.set()

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        return service.run(done)
    finally:
        done.set()
        watcher.join()


def run_with_actor(
    service: LearnerService, learner: Transport, actor: Transport, condition: Callable[[], bool]
) -> LearnerReport:
    """``service`` on ``learner`` with one actor of 16 arenas on ``actor`` (a transport of the same bus), until
    ``condition()`` holds (:func:`run_until`); the actor is stopped and every subscription closed."""
    handles = connect_learner(service, learner)
    robot = RobotActor(actor, ActorConfig(actor_id="a0", arenas=16, batch_size=256, flush_timeout=0.5))
    handles.enter_context(connect_actor(robot, actor))
    stop = threading.Event()
    thread = threading.Thread(target=robot.run, args=(stop,))
    thread.start()
    try:
        return run_until(service, condition)
    finally:
        stop.set()
        thread.join()
        handles.close()  # the ExitStack connect returned: every handle, in reverse order
