"""Learning trials in a simulator slice: tuple semantics, the lost rule, and on-line phase 2."""

from __future__ import annotations

import numpy as np
import pytest

from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.transitions import Batcher, Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from sim import FORMULATIONS, Formulation, scenario
from sim.formulation import DEFAULT_FORMULATION

PAPER = FORMULATIONS["paper"]
LOCAL = Formulation.of("local2d", "paper", "compass")


def test_exploration_tuples_follow_the_trial_rules() -> None:
    cfg = scenario()
    sl = ExperienceSlice(cfg, SliceConfig(PAPER, n_arenas=64), seed=0)
    batch = sl.run_trial()
    robots_total = 64 * cfg.n_robots
    # Every learning robot's trial ends exactly once: lost or at the end of the trial.
    assert batch.done.sum() == robots_total
    decisions = cfg.learning_steps // cfg.action_steps
    assert robots_total <= len(batch) <= robots_total * decisions
    lost = batch.done & (batch.next_state[:, 0] == cfg.mask_value)
    np.testing.assert_array_equal(batch.reward[lost], cfg.lost_reward)
    # Rewards are delayed: non-terminal tuples carry 0.
    assert (batch.reward[~batch.done] == 0).all()
    # Every decision starts with a target in view (a lost robot's trial has ended).
    assert (batch.state[:, 0] != cfg.mask_value).all()
    assert batch.state.dtype == np.float32 and batch.state.shape[1] == 6
    assert set(np.unique(batch.robot)) == set(range(cfg.n_robots))


def test_only_the_named_learners_emit_tuples() -> None:
    cfg = scenario()
    sl = ExperienceSlice(cfg, SliceConfig(PAPER, n_arenas=32, learning_robots=(0, 3)), seed=1)
    batch = sl.run_trial()
    assert set(np.unique(batch.robot)) == {0, 3}
    assert batch.done.sum() == 64


def test_slices_with_the_same_seed_produce_the_same_tuples() -> None:
    cfg = scenario()
    a = ExperienceSlice(cfg, SliceConfig(LOCAL, n_arenas=16), seed=5).run_trial()
    b = ExperienceSlice(cfg, SliceConfig(LOCAL, n_arenas=16), seed=5).run_trial()
    c = ExperienceSlice(cfg, SliceConfig(LOCAL, n_arenas=16), seed=6).run_trial()
    np.testing.assert_array_equal(a.state, b.state)
    np.testing.assert_array_equal(a.reward, b.reward)
    assert len(a) != len(c) or not np.array_equal(a.state, c.state)


def test_a_streamed_trial_hands_on_each_steps_tuples_and_batches_them_as_one_trial_splits() -> None:
    cfg = scenario()
    default = FORMULATIONS[DEFAULT_FORMULATION]
    whole = ExperienceSlice(cfg, SliceConfig(default, n_arenas=24), seed=5).run_trial()
    parts: list[Transitions] = []
    ExperienceSlice(cfg, SliceConfig(default, n_arenas=24), seed=5).stream_trial(parts.append)
    # One part per step that ended an action (every action_steps steps), none holding a whole trial.
    assert len(parts) == cfg.learning_steps // cfg.action_steps and max(map(len, parts)) < len(whole)
    for size in (1, 97, 1000, len(whole), len(whole) + 1):
        sent: list[Transitions] = []
        batcher = Batcher(size, sent.append)
        for part in parts:
            batcher.add(part)
        batcher.flush()
        assert [len(b) for b in sent[:-1]] == [size] * (len(sent) - 1) and 0 < len(sent[-1]) <= size
        assert len(sent) == -(-len(whole) // size)
        joined = Transitions.concat(sent)
        for name in ("robot", "state", "action", "reward", "next_state", "done"):
            np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name))
    before = len(sent)
    batcher = Batcher(5, sent.append)
    batcher.flush()  # nothing held: nothing sent
    assert len(sent) == before
    with pytest.raises(ValueError, match="at least 1"):
        Batcher(0, sent.append)


def test_phase2_learns_that_moving_away_from_a_lone_target_loses_it() -> None:
    cfg = scenario(n_robots=1)
    # Three cells per action on the 2-D local state: target close, far to the east, far to the west.
    protos = [np.array([[0.0, 0.0], [140.0, 0.0], [-140.0, 0.0]])] * 8
    disc = Discretization.from_per_action(protos)
    policy = Policy(LOCAL, disc, np.zeros((1, disc.size), np.float32), np.zeros(1, np.int64))
    agent = TabularAgent(policy, Phase2Config(alpha=0.1, gamma=0.9, epsilon=1.0))
    sl = ExperienceSlice(cfg, SliceConfig(LOCAL, n_arenas=400), seed=2)
    for _ in range(6):
        sl.run_trial(agent, update=True)
    east, west = 2, 6
    q = agent.tables[0]
    target_east = disc.offsets[:-1] + 1
    # With the target far to the east, going West (away) must look worse than going East (towards it).
    assert q[target_east[west]] < q[target_east[east]]
    target_west = disc.offsets[:-1] + 2
    assert q[target_west[east]] < q[target_west[west]]
    assert agent.visits.sum() > 0


def test_n_step_targets_apply_every_tuple_by_the_trials_end_and_learn_other_values() -> None:
    cfg = scenario(n_robots=2)
    protos = [np.array([[0.0, 0.0], [140.0, 0.0], [-140.0, 0.0]])] * 8
    disc = Discretization.from_per_action(protos)
    policy = Policy(LOCAL, disc, np.zeros((1, disc.size), np.float32), np.zeros(2, np.int64))
    tables = {}
    for n_step in (1, 3):
        agent = TabularAgent(policy, Phase2Config(alpha=0.1, gamma=0.9, epsilon=0.5, n_step=n_step))
        sl = ExperienceSlice(cfg, SliceConfig(LOCAL, n_arenas=200), seed=4)
        tuples = sum(len(sl.run_trial(agent, update=True)) for _ in range(3))
        # Each tuple's target is applied once by its trial's end (a lost learner's, the time-out's): none waits.
        assert int(agent.visits.sum()) == tuples
        tables[n_step] = agent.tables.copy()
    assert not np.allclose(tables[1], tables[3])


def test_a_trial_ends_when_its_time_out_falls_between_decisions_after_every_learner_stopped() -> None:
    # Actions of 3 steps in trials of 20: the time-out falls on no decision step, and under the paper's rules many
    # learners have stopped (lost every target) before it. Every learner still ends its trial with exactly one
    # terminal tuple (lost, or the time-out, which is terminal under these rules).
    cfg = scenario(n_robots=2, action_steps=3, learning_steps=20)
    protos = [np.array([[0.0, 0.0], [140.0, 0.0], [-140.0, 0.0]])] * 8
    disc = Discretization.from_per_action(protos)
    policy = Policy(LOCAL, disc, np.zeros((1, disc.size), np.float32), np.zeros(2, np.int64))
    agent = TabularAgent(policy, Phase2Config(epsilon=1.0))
    sl = ExperienceSlice(cfg, SliceConfig(LOCAL, n_arenas=50), seed=3)
    for _ in range(4):
        batch = sl.run_trial(agent, update=True)
        assert int(batch.done.sum()) == 50 * cfg.n_robots


def test_until_change_actions_last_until_the_cell_changes_or_the_cap() -> None:
    cfg = scenario()
    # One prototype per action: the cell never changes, so every VQQL action lasts its cap of 25 steps.
    disc = Discretization.from_per_action([np.zeros((1, 6))] * 8)
    policy = Policy(PAPER, disc, np.zeros((1, disc.size), np.float32), np.zeros(cfg.n_robots, np.int64))
    agent = TabularAgent(policy, Phase2Config())
    config = SliceConfig(PAPER, n_arenas=32, action_mode="until_change", max_action_steps=25)
    batch = ExperienceSlice(cfg, config, seed=3).run_trial(agent)
    robots_total = 32 * cfg.n_robots
    assert batch.done.sum() == robots_total
    # Tuples that do not end a trial end an action: at steps 25, 50 and 75 only.
    assert (~batch.done).sum() <= 3 * robots_total
    fixed = ExperienceSlice(cfg, SliceConfig(PAPER, n_arenas=32), seed=3).run_trial(agent)
    assert (~fixed.done).sum() > (~batch.done).sum()


def test_continuing_trials_start_where_the_last_ended_and_afresh_once_per_test_trial() -> None:
    cfg = scenario("cmommt-v1").replace(learning_steps=10, test_steps=30)  # 3 trials to a test trial's length
    starts: list[np.ndarray] = []
    ends: list[np.ndarray] = []
    rules = FORMULATIONS["frame-cooperative"].replace(trial_rules="continuing")
    sl = ExperienceSlice(cfg, SliceConfig(rules, n_arenas=50), seed=4)
    disc = Discretization.from_per_action([np.zeros((1, rules.dim))] * 8)
    policy = Policy(rules, disc, np.zeros((1, disc.size), np.float32), np.zeros(cfg.n_robots, np.int64))
    agent = TabularAgent(policy, Phase2Config())
    seen: list[np.ndarray] = []
    for _ in range(7):
        seen.clear()
        sl.run_trial(agent, on_step=lambda world, obs: seen.append(world.robot_pos.copy()))
        starts.append(seen[0])
        ends.append(seen[-1])
    step = cfg.robot_speed * (1 + 1e-6)  # one step of a robot, float rounding at the wall aside
    moved = [np.linalg.norm(starts[k] - ends[k - 1], axis=-1).max() for k in range(1, 7)]
    # Trials 1, 2, 4, 5 go on from the last step of the one before (one step apart); 3 and 6 start afresh.
    assert [m <= step for m in moved] == [True, True, False, True, True, False], moved
    # A fresh start is a test trial's: robots uniform in the disk, most of them beyond sensing range of every target
    # (trials that are not continuing put every learner beside one).
    fresh = ExperienceSlice(cfg, SliceConfig(rules, n_arenas=50), seed=4)
    first: list[tuple[np.ndarray, np.ndarray]] = []
    fresh.run_trial(agent, on_step=lambda world, obs: first.append((world.robot_pos.copy(), world.target_pos.copy())))
    robots, targets = first[0]
    nearest = np.linalg.norm(robots[:, :, None] - targets[:, None], axis=-1).min(axis=-1)
    assert (nearest > cfg.sensing_range + step).mean() > 0.5
    # Random exploration (no policy yet), and trials under other rules, put every learner beside a target.
    beside = ExperienceSlice(cfg, SliceConfig(rules, n_arenas=50), seed=4)
    first.clear()
    beside.run_trial(on_step=lambda world, obs: first.append((world.robot_pos.copy(), world.target_pos.copy())))
    robots, targets = first[0]
    nearest = np.linalg.norm(robots[:, :, None] - targets[:, None], axis=-1).min(axis=-1)
    assert (nearest <= cfg.sensing_range + 2 * step).all()
