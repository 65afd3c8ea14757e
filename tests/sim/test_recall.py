"""A robot's memory of the target it lost (:mod:`sim.recall`) and the state that reads it, on hand-built arenas whose
views are known by hand: what is remembered, for how long, that nothing unsensed leaks in, and that a remembering
learner decides where a forgetting one searches."""

from __future__ import annotations

import dataclasses

import numpy as np

from algorithm.discretization import Discretization
from algorithm.policy import Policy, PolicyController
from sim import FORMULATIONS, WorldState, scenario, sense, step_trial
from sim.features import FEATURIZER_REGISTRY
from sim.recall import NEVER, forget_all, recall
from tests.fakes import situation

RECALL = FEATURIZER_REGISTRY["frame10d-recall"]
TOWARD, AWAY = 0, 4  # relative action indices
SPEED = 7.5


def world(robots: list[tuple[float, float]], *targets: tuple[float, float]) -> WorldState:
    return WorldState(
        robot_pos=np.array([robots], dtype=np.float64),
        target_pos=np.array([targets], dtype=np.float64),
        target_vel=np.zeros((1, len(targets), 2)),
        target_speed=np.zeros((1, len(targets))),
    )


def test_a_lost_robot_sees_its_last_target_where_it_saw_it_for_recall_steps_and_no_longer() -> None:
    cfg = scenario(n_robots=2, n_targets=2, recall_steps=3)
    memory = forget_all((1, 2))
    # Robot 0 sees both targets, the nearer (index 1) 50 east; robot 1 sees neither.
    seen = world([(0.0, 0.0), (0.0, 600.0)], (0.0, -120.0), (50.0, 0.0))
    view, memory = recall(cfg, seen, sense(cfg, seen), memory)
    np.testing.assert_array_equal(view.age, [[0, NEVER]])
    np.testing.assert_allclose(memory.point[0, 0], (50.0, 0.0))
    assert memory.target[0, 0] == 1
    # Robot 0 drives 250 west of target 1, out of view of both; the targets move where no robot sees them.
    ages = []
    for step in range(1, 6):
        away = world([(-200.0 - step, 0.0), (0.0, 600.0)], (0.0, -400.0), (50.0, 10.0 * step))
        obs = sense(cfg, away)
        assert obs.n_seen[0, 0] == 0
        view, memory = recall(cfg, away, obs, memory)
        ages.append(int(view.age[0, 0]))
        if step <= cfg.recall_steps:
            assert view.n_seen[0, 0] == 1 and not view.shared[0, 0, 0]
            # Where it saw the target, not where the target is now: nothing unsensed leaks in.
            np.testing.assert_allclose(view.features[0, 0, 0:2], (250.0 + step, 0.0))
            state = RECALL.compute(cfg, view)[0, 0]
            np.testing.assert_allclose(state[[0, 7, 9]], (250.0 + step, 0.0, step))
            assert not RECALL.sees_none(cfg, state)
        else:
            assert view.n_seen[0, 0] == 0
            state = RECALL.compute(cfg, view)[0, 0]
            np.testing.assert_array_equal(state[[0, 3, 9]], 0.0)
            assert RECALL.sees_none(cfg, state)
        # The sensed observation is left as it was.
        assert obs.age is None
    assert ages == [1, 2, 3, 4, 5]
    # A sighting again refreshes the memory.
    back = world([(0.0, 0.0), (0.0, 600.0)], (0.0, 60.0), (500.0, 0.0))
    view, memory = recall(cfg, back, sense(cfg, back), memory)
    assert view.age[0, 0] == 0 and memory.age[0, 0] == 0 and memory.target[0, 0] == 0
    np.testing.assert_allclose(memory.point[0, 0], (0.0, 60.0))


def test_a_remembered_target_a_teammate_sees_now_is_hidden_until_the_teammate_loses_it() -> None:
    cfg = scenario(n_robots=2, n_targets=2, recall_steps=10)
    # Robot 0 sees target 0 (and so remembers it); robot 1, 300 north, sees target 1 only.
    memory = forget_all((1, 2))
    seen = world([(0.0, 0.0), (0.0, 300.0)], (40.0, 0.0), (0.0, 330.0))
    _, memory = recall(cfg, seen, sense(cfg, seen), memory)
    np.testing.assert_array_equal(memory.target, [[0, 1]])
    hidden = []
    # Robot 0 leaves west; target 0 drifts north, into robot 1's view at steps 2 and 3, out of it again after.
    for step, target_y in enumerate((0.0, 200.0, 220.0, 0.0), start=1):
        here = world([(-200.0, 0.0), (0.0, 300.0)], (40.0, target_y), (0.0, 330.0))
        obs = sense(cfg, here)
        view, memory = recall(cfg, here, obs, memory)
        assert obs.n_seen[0, 0] == 0 and view.age[0, 0] == step
        hidden.append(int(view.n_seen[0, 0]) == 0)
        if not hidden[-1]:
            # Where robot 0 saw it, unshared: a teammate watching it would have hidden it.
            np.testing.assert_allclose(view.features[0, 0, 0:2], (240.0, 0.0))
            assert not view.shared[0, 0, 0]
        # Robot 1 sees target 1 and target 0 when it is near, read as sensed either way.
        np.testing.assert_array_equal(view.features[0, 1], obs.features[0, 1])
    assert hidden == [False, True, True, False]


def test_a_robot_that_never_saw_a_target_remembers_nothing() -> None:
    cfg = scenario(n_robots=2, n_targets=1, recall_steps=10**6)
    blind = world([(-400.0, 0.0), (400.0, 0.0)], (0.0, 0.0))
    view, memory = recall(cfg, blind, sense(cfg, blind), forget_all((1, 2)))
    np.testing.assert_array_equal(view.n_seen, 0)
    np.testing.assert_array_equal(memory.age, NEVER)


def test_a_remembering_learner_decides_in_a_frame_pointing_back_where_a_forgetting_one_searches() -> None:
    cfg = scenario(n_robots=1, n_targets=1, action_steps=1, learning_steps=30, recall_steps=5, target_turn_prob=0.0)
    # The target runs east at 20 per step from the robot 145 west of it, which follows at 7.5 and loses it on the
    # first step; the robot remembers it where it last saw it, at the origin.
    common = {"target_vel": [(20.0, 0.0)], "heading": [(0.0, 1.0)]}
    start = ([(-145.0, 0.0)], [(0.0, 0.0)], [True])
    forgetting = situation(cfg, *start, formulation=FORMULATIONS["frame-cooperative"], **common)
    remembering = situation(cfg, *start, formulation=FORMULATIONS["frame-recall"], **common)
    rng = np.random.default_rng(0)
    positions = {}
    for name, state in (("forgetting", forgetting), ("remembering", remembering)):
        decide = np.ones((1, 1), bool)
        trail = []
        for _ in range(8):
            state, out = step_trial(cfg, state, np.full((1, 1), TOWARD), decide, rng)
            decide = out.decide
            trail.append(state.world.robot_pos[0, 0].copy())
        positions[name] = np.array(trail)
    # Forgetting: lost from the first step, it keeps its search heading north.
    np.testing.assert_allclose(np.diff(positions["forgetting"][:, 0]), 0.0, atol=1e-9)
    assert np.all(np.diff(positions["forgetting"][:, 1]) > 0)
    # Remembering: "toward" is the remembered target, so it goes on east to it while its memory lasts, then searches.
    np.testing.assert_allclose(np.diff(positions["remembering"][:6, 0]), SPEED)
    np.testing.assert_allclose(np.diff(positions["remembering"][5:, 0]), 0.0, atol=1e-9)


def test_the_learned_policy_acts_on_a_remembered_target_in_test_trials() -> None:
    cfg = scenario(n_robots=1, n_targets=1, recall_steps=50, target_turn_prob=0.0)
    # One cell per action; the greedy move is always "away".
    q = np.zeros((1, 8), np.float32)
    q[0, AWAY] = 1.0
    policy = Policy(
        formulation=FORMULATIONS["frame-recall"],
        discretization=Discretization.shared(np.zeros((1, RECALL.dim)), 8),
        tables=q,
        robot_table=np.zeros(1, np.int64),
        action_steps=1,
    )
    controller = PolicyController(policy)
    rng = np.random.default_rng(0)
    seen = world([(100.0, 0.0)], (0.0, 0.0))
    memory = controller.init(cfg, seen, rng)
    _, memory = controller.act(cfg, seen, sense(cfg, seen), memory, rng)
    gone = dataclasses.replace(world([(100.0, 0.0)], (-500.0, 0.0)), t=1)
    velocity, memory = controller.act(cfg, gone, sense(cfg, gone), memory, rng)
    assert memory.recall is not None and memory.recall.age[0, 0] == 1
    # The policy's move, "away" from the remembered target (west of the robot): east, not the search heading.
    np.testing.assert_allclose(velocity[0, 0], (cfg.robot_speed, 0.0), atol=1e-9)
    # Past its memory the robot searches.
    far = dataclasses.replace(gone, t=2)
    cfg_short = cfg.replace(recall_steps=1)
    velocity, memory = controller.act(cfg_short, far, sense(cfg_short, far), memory, rng)
    np.testing.assert_allclose(velocity[0, 0], cfg.robot_speed * memory.heading[0, 0], atol=1e-9)
