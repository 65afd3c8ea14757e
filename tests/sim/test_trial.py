"""The learning-trial rules of :mod:`sim.trial` on hand-built arenas whose outcome is known by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim import FORMULATIONS, Formulation, ScenarioConfig, _kernels, reset_trial, scenario, step_trial
from sim.features import trial_reward
from tests.fakes import situation

PAPER = FORMULATIONS["paper"]

N, E, W = 0, 2, 6  # compass action indices
MASK = 1000.0
SPEED = 7.5


def small(m: int, n: int) -> ScenarioConfig:
    return scenario(n_robots=m, n_targets=n, action_steps=3, learning_steps=9, target_turn_prob=0.0)


def test_an_action_is_held_for_exactly_action_steps() -> None:
    cfg = small(1, 1)
    state = situation(cfg, [(0.0, 0.0)], [(0.0, 0.0)], [True])
    rng = np.random.default_rng(0)
    decide = np.ones((1, 1), bool)
    action = np.full((1, 1), E)
    outs = []
    for _ in range(6):
        state, out = step_trial(cfg, state, action, decide, rng)
        outs.append(out)
        action = np.full((1, 1), N)  # offered on every step, taken only at a boundary
        decide = out.decide
    assert [bool(o.boundary[0, 0]) for o in outs] == [False, False, True, False, False, True]
    assert [bool(o.transition[0, 0]) for o in outs] == [False, False, True, False, False, True]
    assert [int(o.action[0, 0]) for o in outs] == [E, E, E, N, N, N]
    np.testing.assert_allclose(state.world.robot_pos[0, 0], (3 * SPEED, 3 * SPEED), atol=1e-9)
    # The tuple of the second action starts where the first ended: target 22.5 to the west.
    np.testing.assert_allclose(outs[5].start_features[0, 0], (-3 * SPEED, 0, -3 * SPEED, 0, MASK, MASK), atol=1e-5)
    np.testing.assert_allclose(outs[2].start_features[0, 0], (0, 0, 0, 0, MASK, MASK), atol=1e-5)


def test_a_learner_that_loses_every_target_is_done_with_the_lost_reward_then_stays_motionless() -> None:
    cfg = small(1, 1)
    # The target drifts east at 1 per step: robot 0 leaves its view at step 2 (155 − 2 > 150), and it is back
    # in view by step 9 (155 − 9 ≤ 150), which must not wake the robot.
    state = situation(cfg, [(140.0, 0.0)], [(0.0, 0.0)], [True], target_vel=[(1.0, 0.0)])
    rng = np.random.default_rng(0)
    decide = np.ones((1, 1), bool)
    state, first = step_trial(cfg, state, np.full((1, 1), E), decide, rng)
    assert not first.done[0, 0] and first.reward[0, 0] == 0.0
    state, out = step_trial(cfg, state, np.full((1, 1), E), first.decide, rng)
    assert out.done[0, 0] and out.transition[0, 0] and not out.boundary[0, 0]
    assert out.reward[0, 0] == cfg.lost_reward == -1.0
    np.testing.assert_array_equal(out.next_features[0, 0], MASK)
    assert not out.decide[0, 0] and not state.active[0, 0]
    lost_at = state.world.robot_pos.copy()
    np.testing.assert_allclose(lost_at[0, 0], (155.0, 0.0))
    while not out.trial_over:
        # Even a caller that insists on new actions cannot move it or give it a second end.
        state, out = step_trial(cfg, state, np.full((1, 1), W), np.ones((1, 1), bool), rng)
        assert not out.done.any() and not out.transition.any() and out.reward[0, 0] == 0.0
        np.testing.assert_array_equal(state.world.robot_pos, lost_at)
    assert state.obs.n_seen[0, 0] == 1


def test_under_search_on_rules_a_lost_learner_searches_and_goes_on_learning() -> None:
    cfg = small(1, 1)
    # As in the test above, robot 0 loses its target at step 2; searching on, it keeps its heading north.
    search_on = PAPER.replace(trial_rules="search-on")
    state = situation(cfg, [(140.0, 0.0)], [(0.0, 0.0)], [True], target_vel=[(1.0, 0.0)], heading=[(0.0, 1.0)])
    state = dataclasses.replace(state, formulation=search_on)
    rng = np.random.default_rng(0)
    decide = np.ones((1, 1), bool)
    outs = []
    for _ in range(cfg.learning_steps):
        state, out = step_trial(cfg, state, np.full((1, 1), E), decide, rng)
        outs.append(out)
        decide = out.decide
    assert not any(o.done[0, 0] for o in outs[:-1])  # losing every target ends nothing
    np.testing.assert_allclose(state.world.robot_pos[0, 0], (155.0, 7 * SPEED), atol=1e-9)  # searched north
    assert [bool(o.transition[0, 0]) for o in outs] == [False, False, True, False, False, True, False, False, True]
    assert outs[2].reward[0, 0] == 0.0  # a trial-end reward is paid only at the end, lost or not
    # Eq. 2's time-out stays terminal (it is paid at the end), and a robot lost at the end is paid lost_reward.
    assert outs[-1].done[0, 0] and outs[-1].reward[0, 0] == cfg.lost_reward


@pytest.mark.parametrize(("trial_rules", "terminal"), [("paper", True), ("search-on", False)])
def test_a_per_decision_rewards_time_out_is_terminal_or_bootstraps_by_the_rules(
    trial_rules: str, terminal: bool
) -> None:
    cfg = small(1, 1)
    formulation = Formulation.of("collab6d", "difference-decision", "compass", trial_rules=trial_rules)
    state = situation(cfg, [(0.0, 0.0)], [(0.0, 0.0)], [True], formulation=formulation)
    rng = np.random.default_rng(0)
    decide = np.ones((1, 1), bool)
    while True:
        state, out = step_trial(cfg, state, np.full((1, 1), N), decide, rng)
        decide = out.decide
        if out.trial_over:
            break
        assert not out.done.any() and not out.truncated.any()
    assert (bool(out.done[0, 0]), bool(out.truncated[0, 0])) == (terminal, not terminal)
    assert out.transition[0, 0] and out.reward[0, 0] == 1.0 and not state.active[0, 0]


@pytest.mark.parametrize(("featurizer", "expected"), [("collab6d", [1.0, 1.0, 2.0]), ("local2d", [3.0, 3.0, 2.0])])
def test_the_reward_is_zero_before_the_end_and_eq2_at_the_end(featurizer: str, expected: list[float]) -> None:
    cfg = small(3, 5)
    # Robots 0 and 1 keep three targets and each other in view (Eq. 2: 3 − k = 3 − 2); robot 2, alone, two.
    targets = [(0.0, 0.0), (10.0, 0.0), (0.0, -10.0), (-600.0, 0.0), (-600.0, 20.0)]
    formulation = Formulation.of(featurizer, "paper", "compass")
    state = situation(cfg, [(0.0, 5.0), (0.0, -5.0), (-600.0, 10.0)], targets, [True] * 3, formulation=formulation)
    rng = np.random.default_rng(0)
    action = np.array([[N, E, W]])
    decide = np.ones((1, 3), bool)
    for t in range(1, cfg.learning_steps + 1):
        state, out = step_trial(cfg, state, action, decide, rng)
        decide = out.decide
        if t < cfg.learning_steps:
            assert not out.trial_over and not out.done.any()
            np.testing.assert_array_equal(out.reward, 0.0)
    assert out.trial_over and out.done.all() and out.transition.all()
    np.testing.assert_array_equal(out.reward[0], expected)
    np.testing.assert_array_equal(out.reward, trial_reward(cfg, state.obs, formulation.reward))
    np.testing.assert_array_equal(state.obs.n_seen[0], [3, 3, 2])
    with pytest.raises(ValueError, match="trial is over"):
        step_trial(cfg, state, action, decide, rng)


def test_learners_start_within_sensing_range_of_a_target() -> None:
    cfg = scenario()
    learners = np.arange(cfg.n_robots) % 3 == 0
    state = reset_trial(cfg, 200, learners, PAPER, np.random.default_rng(3))
    gap = np.linalg.norm(state.world.robot_pos[:, :, None] - state.world.target_pos[:, None], axis=-1).min(axis=2)
    assert (gap[:, learners] <= cfg.sensing_range).all()
    assert (state.obs.n_seen[:, learners] >= 1).all()
    assert (state.obs.n_seen[:, ~learners] == 0).any()  # the others start anywhere in the disk
    np.testing.assert_array_equal(state.active, np.broadcast_to(learners, (200, cfg.n_robots)))
    np.testing.assert_allclose(np.linalg.norm(state.heading, axis=-1), 1.0)
    again = reset_trial(cfg, 200, learners, PAPER, np.random.default_rng(3))
    np.testing.assert_array_equal(again.world.robot_pos, state.world.robot_pos)


def test_lost_robots_that_do_not_learn_wander_with_a_heading_reflected_off_the_wall() -> None:
    cfg = small(3, 1)
    # Robot 0 sees the target and follows its action; robot 1 is lost and keeps its heading north; robot 2 is
    # lost on the wall heading out, so its heading is mirrored back west.
    robots = [(0.0, 0.0), (500.0, 0.0), (1000.0, 0.0)]
    state = situation(cfg, robots, [(0.0, 20.0)], [False] * 3, heading=[(0.0, 1.0), (0.0, 1.0), (1.0, 0.0)])
    state, out = step_trial(cfg, state, np.array([[E, E, E]]), np.ones((1, 3), bool), np.random.default_rng(0))
    np.testing.assert_allclose(state.world.robot_pos[0], [(SPEED, 0.0), (500.0, SPEED), (1000.0 - SPEED, 0.0)])
    np.testing.assert_allclose(state.heading[0, 2], (-1.0, 0.0))
    assert not out.done.any() and not out.transition.any()  # robots that do not learn never end a trial


def test_a_controller_velocity_moves_only_the_robots_that_do_not_learn() -> None:
    cfg = small(2, 1)
    state = situation(cfg, [(0.0, 0.0), (500.0, 0.0)], [(0.0, 0.0)], [True, False])
    velocity = np.array([[(0.0, -SPEED), (0.0, -SPEED)]])
    state, _ = step_trial(
        cfg, state, np.full((1, 2), E), np.ones((1, 2), bool), np.random.default_rng(0), velocity=velocity
    )
    np.testing.assert_allclose(state.world.robot_pos[0], [(SPEED, 0.0), (500.0, -SPEED)], atol=1e-9)


def test_a_caller_boundary_ends_an_action_early_and_hold_sets_the_length() -> None:
    cfg = small(2, 1)
    state = situation(cfg, [(0.0, 0.0), (10.0, 0.0)], [(0.0, 0.0)], [True, True])
    rng = np.random.default_rng(0)
    state, out = step_trial(cfg, state, np.full((1, 2), E), np.ones((1, 2), bool), rng, hold=2)
    assert not out.transition.any()
    early = out.with_boundary(np.array([[True, False]]))
    np.testing.assert_array_equal(early.transition, [[True, False]])
    np.testing.assert_array_equal(early.decide, [[True, False]])
    assert not out.boundary.any()  # the original step is unchanged
    state, out = step_trial(cfg, state, np.full((1, 2), N), early.decide, rng, hold=2)
    np.testing.assert_array_equal(out.boundary, [[False, True]])  # robot 1 held E for 2 steps; robot 0 restarted
    np.testing.assert_array_equal(out.action, [[N, E]])


def test_step_trial_leaves_its_inputs_as_they_were_and_checks_actions() -> None:
    cfg = small(2, 1)
    state = situation(cfg, [(0.0, 0.0), (500.0, 0.0)], [(0.0, 0.0)], [True, False])
    fields = {name: np.copy(getattr(state, name)) for name in ("features", "action", "held", "active", "heading")}
    pos = state.world.robot_pos.copy()
    action, decide = np.full((1, 2), E), np.ones((1, 2), bool)
    step_trial(cfg, state, action, decide, np.random.default_rng(0))
    for name, before in fields.items():
        np.testing.assert_array_equal(getattr(state, name), before)
    np.testing.assert_array_equal(state.world.robot_pos, pos)
    np.testing.assert_array_equal(action, E)
    with pytest.raises(ValueError, match="actions"):
        step_trial(cfg, state, np.full((1, 2), 8), decide, np.random.default_rng(0))
    with pytest.raises(ValueError, match="decide"):
        step_trial(cfg, state, action, np.ones((2, 2), bool), np.random.default_rng(0))


def test_override_moves_equals_the_masked_numpy_rules() -> None:
    rng = np.random.default_rng(4)
    move = rng.normal(size=(50, 10, 2))
    heading = rng.normal(size=(50, 10, 2))
    searching, stopped = rng.random((50, 10)) < 0.4, rng.random((50, 10)) < 0.3
    want = np.where(searching[..., None], 7.5 * heading, move)
    want = np.where(stopped[..., None], 0.0, want)  # a stopped robot stays, searching or not
    _kernels.override_moves(move, searching, heading, 7.5, stopped)
    np.testing.assert_array_equal(move, want)
    assert (searching & stopped).any() and (searching & ~stopped).any()


def test_decision_rewards_equal_the_numpy_arithmetic() -> None:
    rng = np.random.default_rng(8)
    shape = (60, 10)
    decide, lost, ends = (rng.random(shape) < p for p in (0.3, 0.2, 0.5))
    earned = rng.normal(size=shape).astype(np.float32)
    value = rng.integers(-1, 3, shape).astype(np.float32) - np.float32(0.5) * (rng.random(shape) < 0.3)
    held = rng.integers(1, 8, shape)
    want_earned = np.where(decide, np.float32(0.0), earned) + value
    want_mean = (want_earned / held).astype(np.float32)
    want_reward = np.where(ends, np.where(lost, np.float32(-1.0), want_mean), np.float32(0.0)).astype(np.float32)
    got = [np.empty(shape, np.float32) for _ in range(3)]
    _kernels.decision_rewards(decide, earned, value, held, lost, ends, np.float32(-1.0), *got)
    for have, want in zip(got, (want_earned, want_mean, want_reward), strict=True):
        assert have.dtype == np.float32
        np.testing.assert_array_equal(have, want)


@pytest.mark.parametrize("name", ["frame-recall-law", "paper"])
def test_a_lazy_step_leaves_out_only_the_features_nobody_reads(name: str) -> None:
    # The same trial stepped twice from the same seed: lazily, the states between decisions carry no features and
    # every other output is equal; on the steps where an action or the trial ends, the features are the eager ones.
    cfg = scenario(learning_steps=23)
    formulation = FORMULATIONS[name]
    runs = []
    for lazy in (False, True):
        rng = np.random.default_rng(5)
        state = reset_trial(cfg, 6, np.ones(cfg.n_robots, bool), formulation, rng)
        decide = np.ones(state.shape, bool)
        steps = []
        for _ in range(cfg.learning_steps):
            action = rng.integers(0, 8, state.shape)
            state, out = step_trial(cfg, state, action, decide, rng, lazy=lazy)
            steps.append((state, out))
            decide = out.decide
        runs.append(steps)
    read = 0
    for (eager, eager_out), (lazy, lazy_out) in zip(*runs, strict=True):
        ends = bool((eager_out.boundary | eager_out.done | eager_out.truncated).any())
        read += ends
        np.testing.assert_array_equal(lazy.world.robot_pos, eager.world.robot_pos)
        np.testing.assert_array_equal(lazy_out.reward, eager_out.reward)
        np.testing.assert_array_equal(lazy_out.start_features, eager_out.start_features)
        if ends:
            np.testing.assert_array_equal(lazy.require_features(), eager.require_features())
            np.testing.assert_array_equal(lazy_out.require_next_features(), eager_out.require_next_features())
        else:
            assert lazy.features is None and lazy_out.next_features is None
            with pytest.raises(ValueError, match="lazy"):
                lazy.require_features()
            # Deciding on a state whose features were left out is refused, not read as stale.
            with pytest.raises(ValueError, match="lazy"):
                step_trial(cfg, lazy, action, np.ones(lazy.shape, bool), np.random.default_rng(0), lazy=True)
    # Actions of 5 steps in a trial of 23: features on steps 5, 10, 15, 20 and the last, 23 (with every learner's
    # trial over, paper rules end some sooner, which only adds steps).
    assert read >= 5 and read < cfg.learning_steps
