"""The hand-made controllers over the paper's test protocol: 10 seeded trials of 1000 steps."""

from __future__ import annotations

import numpy as np
import pytest

from sim import HAND_MADE, Controller, WorldState, evaluate, scenario, sense


@pytest.fixture(scope="module")
def results() -> dict[str, float]:
    cfg = scenario()
    return {name: evaluate(cfg, c, trials=10, steps=1000, seed=0).coverage_mean for name, c in HAND_MADE.items()}


def test_a_cmommt_is_near_the_calibrated_70_percent(results: dict[str, float]) -> None:
    # The scenario is calibrated to the paper's ≈71% for A-CMOMMT.
    assert 62.0 <= results["a-cmommt"] <= 80.0


def test_random_is_far_below_a_cmommt(results: dict[str, float]) -> None:
    assert 8.0 <= results["random"] <= 28.0
    assert results["a-cmommt"] - results["random"] >= 35.0


def test_local_lies_between_random_and_a_cmommt(results: dict[str, float]) -> None:
    # The paper reports local below 50%; in cmommt-v1 it measures ≈56% (README discusses why).
    assert results["random"] + 20.0 <= results["local"] <= results["a-cmommt"]


def test_random_controller_holds_each_action_for_action_steps() -> None:
    cfg = scenario()
    controller = HAND_MADE["random"]
    from sim import reset, sense, step

    rng = np.random.default_rng(0)
    w = reset(cfg, 4, rng)
    memory = controller.init(cfg, w, rng)
    obs = sense(cfg, w)
    velocities = []
    for _ in range(3 * cfg.action_steps):
        v, memory = controller.act(cfg, w, obs, memory, rng)
        velocities.append(v)
        w = step(cfg, w, v, rng)
        obs = sense(cfg, w)
    v = np.stack(velocities)
    for block in range(3):
        chunk = v[block * cfg.action_steps : (block + 1) * cfg.action_steps]
        assert (chunk == chunk[0]).all()
    assert not (v[0] == v[cfg.action_steps]).all()
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), cfg.robot_speed)


def _arena(robots: list[tuple[float, float]], targets: list[tuple[float, float]]) -> WorldState:
    return WorldState(
        robot_pos=np.array([robots], dtype=np.float64),
        target_pos=np.array([targets], dtype=np.float64),
        target_vel=np.zeros((1, len(targets), 2)),
        target_speed=np.zeros((1, len(targets))),
    )


def _headings(controller: Controller, robots: list[tuple[float, float]], targets: list[tuple[float, float]]):
    cfg = scenario(n_robots=len(robots), n_targets=len(targets))
    world = _arena(robots, targets)
    rng = np.random.default_rng(0)
    memory = controller.init(cfg, world, rng)
    velocity, heading = controller.act(cfg, world, sense(cfg, world), memory, rng)
    np.testing.assert_allclose(np.linalg.norm(velocity, axis=-1), cfg.robot_speed)
    return heading[0], memory[0]


def test_the_state_limited_force_law_on_a_hand_built_arena() -> None:
    # Robot 0 sees target 1 at 30 (nearest: f = (30 - 20) / (40 - 20) = 0.5), target 0 at 100 (furthest: f = 1)
    # and robot 1 at 50 (g = -1, repelling); robot 1 sees both targets too. Robot 2 sees nothing.
    robots = [(0.0, 0.0), (0.0, -50.0), (-900.0, 0.0)]
    targets = [(100.0, 0.0), (0.0, 30.0)]
    heading, memory = _headings(HAND_MADE["force-6d"], robots, targets)
    np.testing.assert_allclose(heading[0], np.array([1.0, 0.5 + 1.0]) / np.hypot(1.0, 1.5), atol=1e-6)
    np.testing.assert_allclose(heading[2], memory[2])  # no force: the heading is kept (inside the wall)
    # With the shared flags both of robot 0's targets weigh 0.25, since robot 1 observes them as well.
    shared, _ = _headings(HAND_MADE["force-6d-shared"], robots, targets)
    np.testing.assert_allclose(shared[0], np.array([0.25, 0.125 + 1.0]) / np.hypot(0.25, 1.125), atol=1e-6)


def test_one_target_in_view_pulls_once_though_it_is_both_nearest_and_furthest() -> None:
    # f = 1 at 100 along +x and g = -1 from the robot at 50 along +y: (1, -1), not (2, -1).
    heading, _ = _headings(HAND_MADE["force-6d"], [(0.0, 0.0), (0.0, 50.0)], [(100.0, 0.0)])
    np.testing.assert_allclose(heading[0], np.array([1.0, -1.0]) / np.sqrt(2.0), atol=1e-6)


def test_the_state_limited_references_sit_between_local_and_a_cmommt(results: dict[str, float]) -> None:
    # Less information, less coverage: the 6-D state's three pairs, then the shared flags, then all of A-CMOMMT.
    assert results["local"] < results["force-6d"] < results["force-6d-shared"] <= results["a-cmommt"] + 1.0
