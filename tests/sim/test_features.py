"""The featurizer and reward registries on hand-built arenas whose values are known by hand, and the formulation
that resolves their names."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from sim import TrialStep, WorldState, featurize, reset, scenario, sense, step_trial
from sim.actions import ACTION_SETS
from sim.features import FEATURIZER_REGISTRY, FEATURIZERS, REWARDS, step_value, trial_reward
from sim.formulation import DEFAULT_FORMULATION, TRIAL_RULES, Formulation, resolve_formulation
from tests.fakes import situation

STATE = FEATURIZER_REGISTRY

MASK = 1000.0
N, W = 0, 6  # compass action indices


def arena() -> WorldState:
    """Robot 0 sees targets 0 (50 away) and 1 (100 away); robot 1, 120 east of robot 0, sees target 0 only (130
    away); target 2 is in nobody's view; robot 2 sees nothing."""
    return WorldState(
        robot_pos=np.array([[(0.0, 0.0), (120.0, 0.0), (-600.0, -600.0)]]),
        target_pos=np.array([[(0.0, 50.0), (-60.0, -80.0), (400.0, 0.0)]]),
        target_vel=np.zeros((1, 3, 2)),
        target_speed=np.zeros((1, 3)),
    )


def test_the_shared_state_flags_the_targets_another_robot_observes() -> None:
    cfg = scenario(n_robots=3, n_targets=3)
    obs = sense(cfg, arena())
    # Robot 0: its nearest target (0) is also robot 1's, its furthest (1) is its own alone.
    np.testing.assert_array_equal(obs.shared[0], [[True, False], [True, True], [False, False]])
    np.testing.assert_array_equal(obs.n_only[0], [1, 0, 0])
    state = featurize(cfg, obs, STATE["shared8d"])[0]
    np.testing.assert_allclose(state[0], [0, 50, -60, -80, 120, 0, 1, 0])
    np.testing.assert_allclose(state[1], [-120, 50, -120, 50, -120, 0, 1, 1])
    np.testing.assert_allclose(state[2], [MASK] * 6 + [0, 0])
    np.testing.assert_array_equal(state[:, :6], featurize(cfg, obs, STATE["collab6d"])[0])
    assert FEATURIZERS["shared8d"] == len(FEATURIZER_REGISTRY["shared8d"].state) == 8


@pytest.mark.parametrize("name", list(FEATURIZER_REGISTRY))
def test_every_featurizer_tells_from_its_state_alone_that_no_target_is_in_view(name: str) -> None:
    cfg = scenario()
    obs = sense(cfg, reset(cfg, 300, np.random.default_rng(2)))
    featurizer = FEATURIZER_REGISTRY[name]
    none = featurizer.sees_none(cfg, featurizer.compute(cfg, obs))
    np.testing.assert_array_equal(none, obs.n_seen == 0)
    assert none.any() and not none.all()


def test_the_difference_reward_counts_the_targets_only_this_robot_observes() -> None:
    cfg = scenario(n_robots=3, n_targets=3)
    obs = sense(cfg, arena())
    # D_i = G(z) − G(z without i): without robot 0 target 1 goes unobserved; without robot 1 nothing changes.
    difference = REWARDS["difference"]
    np.testing.assert_allclose(difference.value(cfg, obs)[0], [1, 0, 0])
    np.testing.assert_allclose(trial_reward(cfg, obs, difference)[0], [1, 0, cfg.lost_reward])
    covered_without = [sense(cfg.replace(n_robots=2), _without(arena(), i)).covered[0] for i in range(cfg.n_robots)]
    np.testing.assert_allclose(difference.value(cfg, obs)[0], obs.covered[0] - np.array(covered_without))


def test_the_redundancy_reward_charges_a_robot_that_sees_only_teammate_watched_targets() -> None:
    # Robot 0 observes target 1 alone (+1); robot 1 sees only target 0, which robot 0 sees too (redundant: −penalty);
    # robot 2 sees nothing (0: searching is not charged).
    for penalty in (0.5, 1.25):
        cfg = scenario(n_robots=3, n_targets=3, redundancy_penalty=penalty)
        value = REWARDS["difference-redundancy"].value(cfg, sense(cfg, arena()))
        np.testing.assert_allclose(value[0], [1.0, -penalty, 0.0])
    assert REWARDS["difference-redundancy"].per_decision
    with pytest.raises(ValueError, match="redundancy_penalty"):
        scenario(redundancy_penalty=float("nan"))


def test_the_shaped_reward_pays_a_redundant_robot_for_each_step_away_from_the_crowd() -> None:
    # Robot 1 sees only target 0 (robot 0 sees it too), 130 away; it steps 5 further east, then out of view.
    cfg = scenario(n_robots=3, n_targets=3, redundancy_penalty=0.5, redundancy_potential=3.0)
    shaped, plain = REWARDS["difference-shaped"], REWARDS["difference-redundancy"]
    world = arena()
    before = sense(cfg, world)
    away = world.robot_pos.copy()
    away[0, 1] = (125.0, 0.0)
    after = sense(cfg, WorldState(away, world.target_pos, world.target_vel, world.target_speed))
    gained = 3.0 * (np.hypot(125.0, 50.0) - 130.0) / cfg.sensing_range
    np.testing.assert_allclose(step_value(cfg, before, after, shaped)[0], [1.0, -0.5 + gained, 0.0], rtol=1e-5)
    # The same step back is charged as much; a plain reward ignores the step; leaving the view settles Φ at 0.
    np.testing.assert_allclose(step_value(cfg, after, before, shaped)[0], [1.0, -0.5 - gained, 0.0], rtol=1e-5)
    np.testing.assert_allclose(step_value(cfg, before, after, plain)[0], plain.value(cfg, after)[0])
    away[0, 1] = (400.0, 400.0)
    gone = sense(cfg, WorldState(away, world.target_pos, world.target_vel, world.target_speed))
    left = 3.0 * (1.0 - np.hypot(125.0, 50.0) / cfg.sensing_range)
    # (robot 0 then watches both its targets alone).
    np.testing.assert_allclose(step_value(cfg, after, gone, shaped)[0], [2.0, left, 0.0], rtol=1e-5)
    with pytest.raises(ValueError, match="redundancy_potential"):
        scenario(redundancy_potential=-1.0)


def _without(world: WorldState, robot: int) -> WorldState:
    keep = np.arange(world.robot_pos.shape[1]) != robot
    return WorldState(world.robot_pos[:, keep], world.target_pos, world.target_vel, world.target_speed)


def test_paper_names_each_featurizers_own_reward_and_unknown_names_are_refused() -> None:
    assert Formulation.of("local2d", "paper", "compass").reward is REWARDS["observed"]
    assert Formulation.of("collab6d", "paper", "compass").reward is REWARDS["eq2"]
    assert Formulation.of("shared8d", "paper", "compass").reward is REWARDS["eq2"]
    assert Formulation.of("collab6d", "difference", "compass").reward is REWARDS["difference"]
    for names, error in [
        (("collab6d", "nope", "compass"), "unknown reward 'nope'; known: paper, observed, eq2"),
        (("pixels", "paper", "compass"), "unknown featurizer 'pixels'; known: local2d, collab6d"),
        (("collab6d", "eq2", "joystick"), "unknown action set 'joystick'; known: compass, relative"),
    ]:
        with pytest.raises(ValueError, match=error):
            Formulation.of(*names)
    with pytest.raises(ValueError, match="unknown trial rules 'lenient'; known: paper, search-on"):
        Formulation.of("collab6d", "eq2", "compass", trial_rules="lenient")
    assert {name for name, r in REWARDS.items() if r.per_decision} == {
        "difference-decision",
        "difference-redundancy",
        "difference-shaped",
        "coverage-split",
    }


def test_coverage_split_pays_each_observed_target_once_shared_evenly_among_its_observers() -> None:
    """Two robots on one target, one alone on another, one on none: 1/2, 1/2, 1, 0; the team's sum is metric A's
    summand (targets covered), whatever the crowding."""
    from sim import scenario
    from sim.world import Observation

    cfg = scenario("cmommt-v1")
    sighted = np.zeros((2, 4, 3), bool)
    sighted[0, 0, 0] = sighted[0, 1, 0] = sighted[0, 2, 1] = True
    sighted[1, :, 2] = True  # every robot on one target
    obs = Observation(
        features=np.zeros((2, 4, 6), np.float32),
        n_seen=sighted.sum(-1).astype(np.int32),
        sees_robot=np.zeros((2, 4), bool),
        covered=sighted.any(1).sum(-1).astype(np.int32),
        shared=np.zeros((2, 4, 2), bool),
        n_only=np.zeros((2, 4), np.int32),
        sighted=sighted,
    )
    value = REWARDS["coverage-split"].value(cfg, obs)
    np.testing.assert_allclose(value, [[0.5, 0.5, 1.0, 0.0], [0.25, 0.25, 0.25, 0.25]])
    np.testing.assert_allclose(value.sum(-1), obs.covered)


@pytest.mark.parametrize("featurizer", list(FEATURIZER_REGISTRY))
def test_a_formulation_of_any_parts_pickles_for_worker_processes(featurizer: str) -> None:
    for rules in TRIAL_RULES:
        formulation = Formulation.of(featurizer, "difference-decision", "relative", act_every=2, trial_rules=rules)
        back = pickle.loads(pickle.dumps(formulation))
        assert back == formulation and back.names == formulation.names and back.trial_rules == formulation.trial_rules
        assert Formulation.parse(formulation.text) == formulation


def test_a_formulations_text_names_every_part_and_reads_back() -> None:
    default = resolve_formulation(DEFAULT_FORMULATION)
    assert default.text == "frame11d-recall/difference-redundancy/law-track/1/guided-search"
    assert Formulation.parse("collab6d/eq2/compass/none/search-on") == resolve_formulation(
        "paper", trial_rules="search-on"
    )
    for text, error in [
        ("collab6d/eq2/compass", "expected featurizer/reward/actions/act_every/rules"),
        ("collab6d/eq2/compass/often/paper", "act_every must be an integer or none"),
        ("collab6d/eq2/joystick/none/paper", "unknown action set 'joystick'"),
    ]:
        with pytest.raises(ValueError, match=error):
            Formulation.parse(text)


def test_a_formulation_is_resolved_by_name_with_explicit_parts_over_it() -> None:
    assert DEFAULT_FORMULATION == "frame-recall-track"
    default = resolve_formulation(DEFAULT_FORMULATION)
    assert default == Formulation.of(
        "frame11d-recall", "difference-redundancy", "law-track", act_every=1, trial_rules="guided-search"
    )
    assert (default.featurizer, default.reward, default.actions, default.trial_rules) == (
        FEATURIZER_REGISTRY["frame11d-recall"],
        REWARDS["difference-redundancy"],
        ACTION_SETS["law-track"],
        TRIAL_RULES["guided-search"],
    )
    assert default.names == ("frame11d-recall", "difference-redundancy", "law-track") and default.dim == 11
    assert resolve_formulation("shared-difference") == Formulation.of("shared8d", "difference", "compass", act_every=1)
    assert resolve_formulation("paper", featurizer="local2d") == Formulation.of("local2d", "eq2", "compass")
    assert resolve_formulation("paper", featurizer="local2d", reward="paper").reward is REWARDS["observed"]
    assert resolve_formulation("shared-difference", act_every=5).act_every == 5
    search = resolve_formulation("paper", trial_rules="search-on")
    assert search != resolve_formulation("paper") and not search.trial_rules.lost_ends_trial
    assert "search-on trial rules" in search.describe()
    assert resolve_formulation("paper").describe() == (
        "collab6d state, eq2 reward, compass moves, deciding every action in tests"
    )
    for kwargs, error in [
        ({"name": "pixels-first"}, "unknown formulation 'pixels-first'; known: paper, shared-difference"),
        ({"name": "paper", "featurizer": "pixels"}, "unknown featurizer 'pixels'"),
        ({"name": "paper", "reward": "money"}, "unknown reward 'money'"),
        ({"name": "paper", "act_every": 0}, "act_every must be at least 1"),
    ]:
        with pytest.raises(ValueError, match=error):
            resolve_formulation(**kwargs)


def _two_robots(reward: str, steps: int, hold: int | None = None) -> list[TrialStep]:
    """Every step of a 10-step trial of 5-step actions, cut after ``steps``: robot 0 goes north with targets
    A (0, 30) and B (−100, 0) in view all along; robot 1 goes west from (200, 30): it sees only target C (300, 30)
    for steps 1–6 and only A from step 7 (at 147.5), so A is shared from then on."""
    cfg = scenario(n_robots=2, n_targets=3, learning_steps=10, action_steps=5)
    robots, targets = [(0.0, 0.0), (200.0, 30.0)], [(0.0, 30.0), (-100.0, 0.0), (300.0, 30.0)]
    state = situation(cfg, robots, targets, [True, True], formulation=Formulation.of("collab6d", reward, "compass"))
    rng = np.random.default_rng(0)
    action, decide = np.array([[N, W]]), np.ones((1, 2), bool)
    outs = []
    for _ in range(steps):
        state, out = step_trial(cfg, state, action, decide, rng, hold=hold)
        outs.append(out)
        decide = out.decide
    return outs


def test_a_per_decision_reward_pays_the_mean_difference_over_each_action() -> None:
    outs = _two_robots("difference-decision", 10)
    paid = [out.reward[0] for out in outs]
    # D per step: robot 0 has 2 for steps 1–6, then 1; robot 1 has 1 for steps 1–6, then 0.
    np.testing.assert_allclose(paid[4], [2.0, 1.0])
    np.testing.assert_allclose(paid[9], [(2 + 4 * 1) / 5, (1 + 4 * 0) / 5], rtol=1e-6)
    assert outs[-1].done.all()
    for t in (0, 1, 2, 3, 5, 6, 7, 8):
        np.testing.assert_array_equal(paid[t], 0.0)


def test_a_caller_boundary_pays_a_per_decision_reward_for_the_steps_held() -> None:
    out = _two_robots("difference-decision", 3, hold=20)[-1].with_boundary(np.array([[True, False]]))
    np.testing.assert_allclose(out.reward[0], [2.0, 0.0])
    assert out.transition[0].tolist() == [True, False]


def test_a_trial_end_difference_reward_is_paid_once_at_the_end() -> None:
    outs = _two_robots("difference", 10)
    np.testing.assert_allclose(outs[-1].reward[0], [1.0, 0.0])
    np.testing.assert_allclose(np.sum([out.reward[0] for out in outs], axis=0), [1.0, 0.0])
