"""A robot's tracks of the targets it lost (:mod:`sim.recall`) and the state that reads them, on hand-built arenas whose
views are known by hand: which target is remembered and where it is predicted, for how long, that nothing unsensed
leaks in, that a target a teammate watches is left to it, and that a remembering learner decides where a forgetting
one searches."""

from __future__ import annotations

import dataclasses

import numpy as np

from algorithm.discretization import Discretization
from algorithm.policy import Policy, PolicyController
from sim import FORMULATIONS, WorldState, scenario, sense, step_trial
from sim.controllers import HAND_MADE
from sim.features import FEATURIZER_REGISTRY
from sim.recall import NEVER, forget_all, recall
from tests.fakes import situation

RECALL = FEATURIZER_REGISTRY["frame11d-recall"]
TOWARD, AWAY = 0, 4  # relative action indices
SPEED = 7.5


def world(robots: list[tuple[float, float]], *targets: tuple[float, float]) -> WorldState:
    return WorldState(
        robot_pos=np.array([robots], dtype=np.float64),
        target_pos=np.array([targets], dtype=np.float64),
        target_vel=np.zeros((1, len(targets), 2)),
        target_speed=np.zeros((1, len(targets))),
    )


def test_a_lost_robot_sees_its_lost_target_where_its_own_sightings_predict_it_for_recall_steps() -> None:
    cfg = scenario(n_robots=2, n_targets=2, recall_steps=3)
    memory = forget_all(cfg, (1, 2))
    # Robot 0 sees target 1 twice, 10 further east each step; robot 1 (far north) sees neither.
    for x in (40.0, 50.0):
        seen = world([(0.0, 0.0), (0.0, 600.0)], (0.0, -400.0), (x, 0.0))
        view, memory = recall(cfg, seen, sense(cfg, seen), memory)
    np.testing.assert_allclose(memory.position[0, 0, 1], (50.0, 0.0))
    np.testing.assert_allclose(memory.velocity[0, 0, 1], (10.0, 0.0))
    assert memory.age[0, 0, 1] == 0 and memory.age[0, 0, 0] == NEVER
    assert not view.remembers.any()
    # Robot 0 jumps 250 west, out of view; unseen, the target turns north instead of going on east.
    for step in range(1, 6):
        away = world([(-200.0, 0.0), (0.0, 600.0)], (0.0, -400.0), (50.0, 10.0 * step))
        obs = sense(cfg, away)
        assert obs.n_seen[0, 0] == 0
        view, memory = recall(cfg, away, obs, memory)
        state = RECALL.compute(cfg, view)[0, 0]
        if step <= cfg.recall_steps:
            assert view.n_seen[0, 0] == 1 and not view.shared[0, 0].any()
            # Where its sightings predict it, not where the target is: nothing unsensed leaks in.
            np.testing.assert_allclose(view.features[0, 0, 0:2], (250.0 + 10.0 * step, 0.0))
            np.testing.assert_allclose(state[[0, 7, 9, 10]], (250.0 + 10.0 * step, 0.0, 0.0, 0.0))
            assert not RECALL.sees_none(cfg, state)
        else:
            assert view.n_seen[0, 0] == 0
            np.testing.assert_array_equal(state[[0, 3, 9, 10]], 0.0)
            assert RECALL.sees_none(cfg, state)
        # The sensed observation is left as it was.
        assert obs.memory is None and obs.n_seen[0, 0] == 0
    np.testing.assert_array_equal(memory.age[0, 0], [NEVER, 5])


def test_a_robot_that_sees_a_target_reads_the_nearest_remembered_one_beside_it() -> None:
    cfg = scenario(n_robots=1, n_targets=4, recall_steps=10)
    memory = forget_all(cfg, (1, 1))
    seen = world([(0.0, 0.0)], (100.0, 0.0), (0.0, 120.0), (0.0, -140.0), (30.0, 0.0))
    _, memory = recall(cfg, seen, sense(cfg, seen), memory)
    # The robot moves 200 east. It sees target 3 (now 20 north-east of it); targets 0 and 2 are lost, target 1 is
    # lost too but predicted (still) 100 from the robot's old spot, 224 from the new; target 0's prediction lies 100
    # west, inside the sensing range, so it is known to be wrong and passed over.
    moved = world([(200.0, 0.0)], (100.0, -500.0), (0.0, 120.0 + 500.0), (0.0, -640.0), (220.0, 0.0))
    view, memory = recall(cfg, moved, sense(cfg, moved), memory)
    assert view.n_seen[0, 0] == 1 and view.remembers[0, 0]
    np.testing.assert_allclose(view.memory[0, 0], (-200.0, 120.0))
    np.testing.assert_allclose(view.features[0, 0, 0:2], (20.0, 0.0))
    # In the target frame (x east, towards target 3) the remembered target's direction is west and north.
    state = RECALL.compute(cfg, view)[0, 0]
    direction = np.array([-200.0, 120.0]) / np.hypot(200.0, 120.0)
    np.testing.assert_allclose(abs(state[9:]), abs(direction), rtol=1e-6)
    assert state[9] < 0
    # The law on the state's information feels it: remembered, the robot's move turns from the target in view.
    law = HAND_MADE["force-6d-shared"]
    heading = np.array([[[0.0, 1.0]]])
    with_memory, _ = law.act(cfg, moved, view, heading, np.random.default_rng(0))
    without, _ = law.act(cfg, moved, sense(cfg, moved), heading, np.random.default_rng(0))
    assert with_memory[0, 0, 0] < without[0, 0, 0]


def test_a_remembered_target_a_teammate_sees_now_is_hidden_until_the_teammate_loses_it() -> None:
    cfg = scenario(n_robots=2, n_targets=2, recall_steps=10)
    # Robot 0 sees target 0; robot 1, 300 north, sees target 1 only.
    memory = forget_all(cfg, (1, 2))
    seen = world([(0.0, 0.0), (0.0, 300.0)], (40.0, 0.0), (0.0, 330.0))
    _, memory = recall(cfg, seen, sense(cfg, seen), memory)
    hidden = []
    # Robot 0 leaves west; target 0 drifts north, into robot 1's view at steps 2 and 3, out of it again after.
    for target_y in (0.0, 200.0, 220.0, 0.0):
        here = world([(-200.0, 0.0), (0.0, 300.0)], (40.0, target_y), (0.0, 330.0))
        obs = sense(cfg, here)
        view, memory = recall(cfg, here, obs, memory)
        assert obs.n_seen[0, 0] == 0
        hidden.append(int(view.n_seen[0, 0]) == 0)
        if not hidden[-1]:
            # Where robot 0 saw it (a first sighting: no velocity), unshared.
            np.testing.assert_allclose(view.features[0, 0, 0:2], (240.0, 0.0))
            assert not view.shared[0, 0, 0]
        # Robot 1 sees target 1 and target 0 when it is near, read as sensed either way.
        np.testing.assert_array_equal(view.features[0, 1], obs.features[0, 1])
    assert hidden == [False, True, True, False]


def test_a_robot_that_never_saw_a_target_remembers_nothing() -> None:
    cfg = scenario(n_robots=2, n_targets=1, recall_steps=10**6)
    blind = world([(-400.0, 0.0), (400.0, 0.0)], (0.0, 0.0))
    view, memory = recall(cfg, blind, sense(cfg, blind), forget_all(cfg, (1, 2)))
    np.testing.assert_array_equal(view.n_seen, 0)
    assert not view.remembers.any()
    np.testing.assert_array_equal(memory.age, NEVER)


def test_a_remembering_learner_decides_in_a_frame_pointing_back_where_a_forgetting_one_searches() -> None:
    cfg = scenario(n_robots=1, n_targets=1, action_steps=1, learning_steps=30, recall_steps=5, target_turn_prob=0.0)
    # The target runs east at 20 per step from the robot 100 west of it, which follows at 7.5: it sees the target
    # for 4 steps (so knows its velocity) and loses it on the fifth; then its prediction, exact here, runs away east.
    common = {"target_vel": [(20.0, 0.0)], "heading": [(0.0, 1.0)]}
    start = ([(-100.0, 0.0)], [(0.0, 0.0)], [True])
    forgetting = situation(cfg, *start, formulation=FORMULATIONS["frame-cooperative"], **common)
    remembering = situation(cfg, *start, formulation=FORMULATIONS["frame-recall"], **common)
    rng = np.random.default_rng(0)
    positions = {}
    for name, state in (("forgetting", forgetting), ("remembering", remembering)):
        decide = np.ones((1, 1), bool)
        trail = []
        for _ in range(14):
            state, out = step_trial(cfg, state, np.full((1, 1), TOWARD), decide, rng)
            decide = out.decide
            trail.append(state.world.robot_pos[0, 0].copy())
        positions[name] = np.array(trail)
    # Both follow east while they see the target (steps 1-5); forgetting, the robot then keeps its search heading.
    for name in positions:
        np.testing.assert_allclose(np.diff(positions[name][:5, 0]), SPEED)
    np.testing.assert_allclose(np.diff(positions["forgetting"][4:, 0]), 0.0, atol=1e-9)
    assert np.all(np.diff(positions["forgetting"][4:, 1]) > 0)
    # Remembering: "toward" is the predicted target, so it goes on east while its memory lasts, then searches.
    np.testing.assert_allclose(np.diff(positions["remembering"][4:10, 0]), SPEED)
    np.testing.assert_allclose(np.diff(positions["remembering"][10:, 0]), 0.0, atol=1e-9)


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
    gone = dataclasses.replace(world([(200.0, 0.0)], (-500.0, 0.0)), t=1)
    velocity, memory = controller.act(cfg, gone, sense(cfg, gone), memory, rng)
    assert memory.recall is not None and memory.recall.age[0, 0, 0] == 1
    # The policy's move, "away" from the remembered target (west of the robot): east, not the search heading.
    np.testing.assert_allclose(velocity[0, 0], (cfg.robot_speed, 0.0), atol=1e-9)
    # Past its memory the robot searches.
    far = dataclasses.replace(gone, t=2)
    cfg_short = cfg.replace(recall_steps=1)
    velocity, memory = controller.act(cfg_short, far, sense(cfg_short, far), memory, rng)
    np.testing.assert_allclose(velocity[0, 0], cfg.robot_speed * memory.heading[0, 0], atol=1e-9)


def test_tracks_updated_in_place_are_the_tracks_a_pure_call_returns_and_a_pure_call_keeps_its_input() -> None:
    from sim import reset, step

    cfg = scenario()
    rng = np.random.default_rng(4)
    here = reset(cfg, 50, rng)
    pure, kept = forget_all(cfg, (50, cfg.n_robots)), forget_all(cfg, (50, cfg.n_robots))
    for _ in range(150):
        obs = sense(cfg, here, rng)
        before = (pure.position.copy(), pure.velocity.copy(), pure.age.copy())
        view, after = recall(cfg, here, obs, pure)
        # The pure call leaves its input as it was.
        for was, now in zip(before, (pure.position, pure.velocity, pure.age), strict=True):
            np.testing.assert_array_equal(was, now)
        same, updated = recall(cfg, here, obs, kept, in_place=True)
        assert updated is kept
        for a, b in zip(
            (after.position, after.velocity, after.age), (kept.position, kept.velocity, kept.age), strict=True
        ):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(view.features, same.features)
        np.testing.assert_array_equal(view.memory, same.memory)
        pure = after
        here = step(cfg, here, cfg.robot_speed * rng.normal(size=here.robot_pos.shape) / 2, rng)
    # Over 150 steps some robots lost targets and remember them: the comparison covered the tracks that matter.
    assert (pure.age[(pure.age > 0) & (pure.age < NEVER)]).size > 100 and view.remembers.any()


def test_the_tracks_read_the_sightings_sense_made_and_measure_the_same_without_them() -> None:
    from sim import reset, step
    from sim.recall import sightings

    cfg = scenario()
    rng = np.random.default_rng(5)
    here = reset(cfg, 40, rng)
    given, measured = forget_all(cfg, (40, cfg.n_robots)), forget_all(cfg, (40, cfg.n_robots))
    for _ in range(120):
        obs = sense(cfg, here, rng)
        assert obs.sighted is not None
        # sense's sightings are the true-distance ones, and what each robot counts as in view.
        np.testing.assert_array_equal(obs.sighted, sightings(cfg, here))
        np.testing.assert_array_equal(obs.sighted.sum(axis=2), obs.n_seen)
        view, given = recall(cfg, here, obs, given, in_place=True)
        again, measured = recall(cfg, here, dataclasses.replace(obs, sighted=None), measured, in_place=True)
        for name in ("position", "velocity", "age"):
            np.testing.assert_array_equal(getattr(given, name), getattr(measured, name))
        np.testing.assert_array_equal(view.features, again.features)
        here = step(cfg, here, cfg.robot_speed * rng.normal(size=here.robot_pos.shape) / 2, rng)
    assert view.remembers is not None and view.remembers.any() and (given.age == 0).any()


def _tracks_by_hand(cfg, here, memory):
    """The module docstring's rule, pair by pair in plain Python: the tracks after this step, each robot's remembered
    offset (None: none)."""
    r, n = cfg.sensing_range, here.target_pos.shape[1]
    position, velocity, age = memory.position.copy(), memory.velocity.copy(), memory.age.copy()
    remembered = {}
    for e in range(here.robot_pos.shape[0]):
        d = here.target_pos[e][None, :, :] - here.robot_pos[e][:, None, :]
        sees = (d**2).sum(-1) <= r * r
        for i in range(here.robot_pos.shape[1]):
            best = None
            for j in range(n):
                if sees[i, j]:
                    gap = age[e, i, j] + 1 if age[e, i, j] < NEVER else None
                    velocity[e, i, j] = 0.0 if gap is None else (here.target_pos[e, j] - position[e, i, j]) / gap
                    position[e, i, j], age[e, i, j] = here.target_pos[e, j], 0
                elif age[e, i, j] < NEVER:
                    age[e, i, j] += 1
                    if not sees[:, j].any() and age[e, i, j] <= cfg.recall_steps:
                        off = position[e, i, j] + age[e, i, j] * velocity[e, i, j] - here.robot_pos[e, i]
                        d2 = float(off @ off)
                        if d2 > r * r and (best is None or d2 < best[0]):
                            best = (d2, off)
            remembered[e, i] = None if best is None else best[1]
    return position, velocity, age, remembered


def test_tracks_of_more_than_64_targets_follow_the_rule_pair_by_pair() -> None:
    # 70 targets: a robot's known tracks span three words of 32. Small arena, wide sensing: many sightings and losses.
    from sim import reset, step

    cfg = scenario(n_robots=3, n_targets=70, arena_radius=400.0, recall_steps=30)
    rng = np.random.default_rng(8)
    here = reset(cfg, 4, rng)
    memory = forget_all(cfg, (4, cfg.n_robots))
    remembered_any = far_words = 0
    for _ in range(60):
        obs = sense(cfg, here, rng)
        position, velocity, age, remembered = _tracks_by_hand(cfg, here, memory)
        view, memory = recall(cfg, here, obs, memory, in_place=True)
        np.testing.assert_array_equal(memory.age, age)
        np.testing.assert_allclose(memory.position, position, rtol=0, atol=1e-9)
        np.testing.assert_allclose(memory.velocity, velocity, rtol=0, atol=1e-9)
        for (e, i), offset in remembered.items():
            assert bool(view.remembers[e, i]) == (offset is not None)
            if offset is not None:
                np.testing.assert_allclose(view.memory[e, i], offset, rtol=1e-6, atol=1e-3)
                remembered_any += 1
        held = memory.age < NEVER
        far_words += int(held[..., 64:].any())
        for w in range(memory.known.shape[-1]):
            part = held[..., 32 * w : 32 * (w + 1)]
            expected = (part.astype(np.int64) << np.arange(part.shape[-1])).sum(-1)
            np.testing.assert_array_equal(memory.known[..., w], expected)
        here = step(cfg, here, cfg.robot_speed * rng.normal(size=here.robot_pos.shape) / 2, rng)
    assert remembered_any > 20 and far_words > 0
