"""Physics, sensing, featurizers, rewards and metric A of the CMOMMT world."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim import (
    HAND_MADE,
    WorldState,
    coverage,
    evaluate,
    featurize,
    lost,
    reset,
    scenario,
    sense,
    step,
    trial_reward,
)
from sim.features import FEATURIZER_REGISTRY, REWARDS
from sim.world import place_near_targets

MASK = 1000.0


def world(robots: list[tuple[float, float]], targets: list[tuple[float, float]]) -> WorldState:
    """One arena with robots and still targets at the given positions."""
    n = len(targets)
    return WorldState(
        robot_pos=np.array([robots], dtype=np.float64),
        target_pos=np.array([targets], dtype=np.float64),
        target_vel=np.zeros((1, n, 2)),
        target_speed=np.zeros((1, n)),
    )


def small_cfg(m: int, n: int, **kw: object):
    return scenario(n_robots=m, n_targets=n, **kw)


def test_nearest_furthest_and_robot_features_on_a_hand_built_arena() -> None:
    cfg = small_cfg(3, 3)
    # Robot 0 sees targets 0 (dist 50) and 1 (dist 100) but not 2 (dist 400); robot 1 is 120 away (in view).
    w = world(
        robots=[(0.0, 0.0), (120.0, 0.0), (-600.0, -600.0)],
        targets=[(0.0, 50.0), (-60.0, -80.0), (400.0, 0.0)],
    )
    obs = sense(cfg, w)
    f = obs.features[0]
    np.testing.assert_allclose(f[0], [0, 50, -60, -80, 120, 0])
    # Robot 1: target 0 at (-120, 50) -> 130 in view; target 2 at 280 out of view; robot 0 at 120 in view.
    np.testing.assert_allclose(f[1], [-120, 50, -120, 50, -120, 0])
    # Robot 2 sees nothing: every pair masked.
    np.testing.assert_allclose(f[2], [MASK] * 6)
    np.testing.assert_array_equal(obs.n_seen[0], [2, 1, 0])
    np.testing.assert_array_equal(obs.sees_robot[0], [True, True, False])
    assert obs.covered[0] == 2
    local = featurize(cfg, obs, FEATURIZER_REGISTRY["local2d"])[0]
    np.testing.assert_allclose(local, [[-60, -80], [-120, 50], [MASK, MASK]])
    nearest = featurize(cfg.replace(local_target="nearest"), obs, FEATURIZER_REGISTRY["local2d"])[0]
    np.testing.assert_allclose(nearest, [[0, 50], [-120, 50], [MASK, MASK]])


def test_sensing_range_is_inclusive_and_nearest_robot_is_chosen() -> None:
    cfg = small_cfg(3, 1)
    w = world(robots=[(0.0, 0.0), (0.0, 150.0), (0.0, -90.0)], targets=[(150.0, 0.0)])
    obs = sense(cfg, w)
    assert obs.n_seen[0, 0] == 1  # exactly at r_s counts as observed
    np.testing.assert_allclose(obs.features[0, 0, 4:6], [0, -90])  # nearer of the two robots in view


def test_rewards_follow_equation_2_and_the_lost_rule() -> None:
    cfg = small_cfg(3, 3)
    w = world(
        robots=[(0.0, 0.0), (120.0, 0.0), (-600.0, -600.0)],
        targets=[(0.0, 50.0), (-60.0, -80.0), (400.0, 0.0)],
    )
    obs = sense(cfg, w)
    # r_i(T) = Σ_j b_ij(T) − k(T), k = 2 when another robot is in view [paper Eq. 2]; lost robots get −1.
    np.testing.assert_allclose(trial_reward(cfg, obs, REWARDS["eq2"])[0], [2 - 2, 1 - 2, -1])
    np.testing.assert_allclose(trial_reward(cfg, obs, REWARDS["observed"])[0], [2, 1, -1])
    np.testing.assert_array_equal(lost(obs)[0], [False, False, True])
    custom = cfg.replace(lost_reward=-5.0, robot_in_view_penalty=0.5)
    np.testing.assert_allclose(trial_reward(custom, obs, REWARDS["eq2"])[0], [1.5, 0.5, -5])


def brute_force_coverage(cfg, w: WorldState) -> np.ndarray:
    out = []
    for e in range(w.n_arenas):
        seen = 0
        for j in range(cfg.n_targets):
            observed = False
            for i in range(cfg.n_robots):
                d = np.hypot(*(w.target_pos[e, j] - w.robot_pos[e, i]))
                observed = observed or d <= cfg.sensing_range
            seen += observed
        out.append(100.0 * seen / cfg.n_targets)
    return np.array(out)


def test_metric_a_matches_a_brute_force_recomputation() -> None:
    cfg = small_cfg(4, 5)
    rng = np.random.default_rng(3)
    w = reset(cfg, 6, rng)
    controller = HAND_MADE["a-cmommt"]
    memory = controller.init(cfg, w, rng)
    obs = sense(cfg, w)
    fast = np.zeros(6)
    slow = np.zeros(6)
    for _ in range(60):
        v, memory = controller.act(cfg, w, obs, memory, rng)
        w = step(cfg, w, v, rng)
        obs = sense(cfg, w)
        fast += coverage(cfg, obs)
        slow += brute_force_coverage(cfg, w)
    np.testing.assert_allclose(fast, slow)
    assert slow.max() > 0  # the comparison is not vacuous


def test_everything_stays_inside_the_arena_and_targets_keep_their_speed() -> None:
    cfg = scenario()
    rng = np.random.default_rng(11)
    w = reset(cfg, 32, rng)
    speed0 = w.target_speed.copy()
    for name in ("random", "a-cmommt"):
        controller = HAND_MADE[name]
        memory = controller.init(cfg, w, rng)
        obs = sense(cfg, w)
        for _ in range(400):
            v, memory = controller.act(cfg, w, obs, memory, rng)
            w = step(cfg, w, v, rng)
            obs = sense(cfg, w)
            assert np.linalg.norm(w.robot_pos, axis=-1).max() <= cfg.arena_radius + 1e-9
            assert np.linalg.norm(w.target_pos, axis=-1).max() <= cfg.arena_radius + 1e-9
    np.testing.assert_allclose(np.linalg.norm(w.target_vel, axis=-1), speed0, rtol=1e-9, atol=1e-12)
    assert w.t == 800


def test_step_is_pure_and_clips_robot_speed() -> None:
    cfg = small_cfg(2, 1, target_turn_prob=0.0)
    w = world(robots=[(0.0, 0.0), (10.0, 0.0)], targets=[(0.0, 0.0)])
    before = dataclasses.replace(w, robot_pos=w.robot_pos.copy())
    w2 = step(cfg, w, np.array([[[30.0, 40.0], [0.0, 3.0]]]), np.random.default_rng(0))
    np.testing.assert_array_equal(w.robot_pos, before.robot_pos)
    np.testing.assert_allclose(w2.robot_pos[0], [[4.5, 6.0], [10.0, 3.0]])  # 50 clipped to 7.5 along (3, 4)
    with pytest.raises(ValueError, match="shape"):
        step(cfg, w, np.zeros((1, 3, 2)), np.random.default_rng(0))


def test_robots_at_the_wall_are_projected_back_onto_the_disk() -> None:
    cfg = small_cfg(1, 1)
    w = world(robots=[(0.0, 999.0)], targets=[(0.0, 0.0)])
    w2 = step(cfg, w, np.array([[[0.0, 7.5]]]), np.random.default_rng(0))
    np.testing.assert_allclose(w2.robot_pos[0, 0], [0.0, 1000.0])


def test_targets_reflect_specularly_off_the_wall() -> None:
    cfg = small_cfg(1, 1, target_turn_prob=0.0)
    w = WorldState(
        robot_pos=np.zeros((1, 1, 2)),
        target_pos=np.array([[[998.0, 0.0]]]),
        target_vel=np.array([[[4.0, 0.0]]]),
        target_speed=np.array([[4.0]]),
    )
    w2 = step(cfg, w, np.zeros((1, 1, 2)), np.random.default_rng(0))
    np.testing.assert_allclose(w2.target_pos[0, 0], [998.0, 0.0])  # 2 past the wall, mirrored 2 back inside
    np.testing.assert_allclose(w2.target_vel[0, 0], [-4.0, 0.0])


def test_force_law_attracts_repels_and_cooperates() -> None:
    cfg = small_cfg(2, 1)
    a_cmommt = HAND_MADE["a-cmommt-public"]  # the public parameters the distances below are laid out for
    rng = np.random.default_rng(0)

    def heading(robots, targets, controller=a_cmommt):
        w = world(robots, targets)
        v, _ = controller.act(cfg, w, sense(cfg, w), controller.init(cfg, w, rng), rng)
        np.testing.assert_allclose(np.linalg.norm(v, axis=-1), cfg.robot_speed)
        return v[0] / cfg.robot_speed

    # A target at 100 attracts; one at 10 (inside do1 = 20) repels; robots 50 apart push each other away.
    np.testing.assert_allclose(heading([(0, 0), (-900, 0)], [(100, 0)])[0], [1, 0], atol=1e-12)
    np.testing.assert_allclose(heading([(0, 0), (-900, 0)], [(10, 0)])[0], [-1, 0], atol=1e-12)
    h = heading([(0, 0), (50, 0)], [(0, -900)])
    np.testing.assert_allclose(h, [[-1, 0], [1, 0]], atol=1e-12)
    # Robot 1 already observes the target: A-CMOMMT weighs it 0.25 for robot 0, so the repulsion from robot 1
    # (g = -1 at 60 < dr1) wins; the local controller ignores robots and still heads for the target.
    robots = [(0.0, 0.0), (0.0, 60.0)]
    target = [(0.0, 120.0)]
    assert heading(robots, target)[0][1] < 0
    assert heading(robots, target, HAND_MADE["local"])[0][1] > 0


def test_place_near_targets_puts_the_robot_in_view_of_a_target() -> None:
    cfg = scenario()
    rng = np.random.default_rng(5)
    w = reset(cfg, 200, rng)
    chosen = np.zeros((200, cfg.n_robots), dtype=bool)
    chosen[:, 0] = True
    w2 = place_near_targets(cfg, w, chosen, rng)
    assert (sense(cfg, w2).n_seen[:, 0] >= 1).all()
    np.testing.assert_array_equal(w2.robot_pos[:, 1:], w.robot_pos[:, 1:])
    assert np.linalg.norm(w2.robot_pos, axis=-1).max() <= cfg.arena_radius + 1e-9


def test_evaluation_is_deterministic_under_a_seed() -> None:
    cfg = scenario()
    for name in HAND_MADE:
        a = evaluate(cfg, HAND_MADE[name], trials=3, steps=200, seed=7)
        b = evaluate(cfg, HAND_MADE[name], trials=3, steps=200, seed=7)
        c = evaluate(cfg, HAND_MADE[name], trials=3, steps=200, seed=8)
        np.testing.assert_array_equal(a.coverage_per_trial, b.coverage_per_trial)
        assert not np.array_equal(a.coverage_per_trial, c.coverage_per_trial)


def test_sensor_noise_perturbs_features_but_not_observation_counts() -> None:
    cfg = scenario(sensor_noise_std=5.0)
    w = reset(cfg, 50, np.random.default_rng(0))
    clean = sense(scenario(), w)
    noisy = sense(cfg, w, np.random.default_rng(1))
    np.testing.assert_array_equal(clean.n_seen, noisy.n_seen)
    in_view = clean.n_seen > 0
    assert in_view.any()
    diff = noisy.features[in_view][:, :4] - clean.features[in_view][:, :4]
    assert 2.0 < diff.std() < 8.0
    np.testing.assert_array_equal(noisy.features[~in_view][:, :4], MASK)
    with pytest.raises(ValueError, match="rng"):
        sense(cfg, w)


def test_config_rejects_bad_values_and_unknown_fields() -> None:
    with pytest.raises(TypeError):
        scenario(no_such_field=1)
    with pytest.raises(ValueError, match="sensing_range"):
        scenario(sensing_range=-1.0)
    with pytest.raises(ValueError, match="mask_value"):
        scenario(mask_value=100.0)
    with pytest.raises(ValueError, match="unknown scenario"):
        scenario("cmommt-v9")
    with pytest.raises(ValueError, match="n_arenas"):
        reset(scenario(), 0, np.random.default_rng(0))
