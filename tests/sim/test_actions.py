"""Action sets, the target frame and the featurizers built on it, on hand-built arenas with values known by hand."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sim import WorldState, featurize, scenario, sense
from sim.actions import ACTION_SETS, target_frame
from sim.features import FEATURIZER_REGISTRY as STATE
from sim.formulation import Formulation
from sim.trial import reset_trial, step_trial

FRAME9D = STATE["frame9d"]

SPEED = 7.5


def _world(robots: list[tuple[float, float]], targets: list[tuple[float, float]], vel=None) -> WorldState:
    v = np.zeros((1, len(targets), 2)) if vel is None else np.array([vel], dtype=np.float64)
    return WorldState(
        robot_pos=np.array([robots], dtype=np.float64),
        target_pos=np.array([targets], dtype=np.float64),
        target_vel=v,
        target_speed=np.linalg.norm(v, axis=-1),
    )


def _observe(robots, targets):
    cfg = scenario(n_robots=len(robots), n_targets=len(targets))
    return cfg, sense(cfg, _world(robots, targets))


# Robot 0 at the origin: nearest target (0, 100) due north, furthest (-120, 50) (d = 130), robot 1 at (60, 0). Robot 1
# sees the nearest target too (d = 116.6), not the furthest (d = 186.8).
ROBOTS = [(0.0, 0.0), (60.0, 0.0)]
TARGETS = [(0.0, 100.0), (-120.0, 50.0)]
MIRRORED = [(0.0, 100.0), (120.0, 50.0)]


def test_the_target_frame_points_at_the_nearest_target_with_the_furthest_on_its_left() -> None:
    _, obs = _observe(ROBOTS, TARGETS)
    frame = target_frame(obs)[0, 0]
    np.testing.assert_allclose(frame, [[0.0, 1.0], [-1.0, 0.0]], atol=1e-12)  # x north; y west, the furthest's side
    _, obs = _observe(ROBOTS, MIRRORED)
    np.testing.assert_allclose(target_frame(obs)[0, 0], [[0.0, 1.0], [1.0, 0.0]], atol=1e-12)  # mirrored: y east


def test_frame9d_is_the_same_state_in_a_mirror_and_under_a_rotation() -> None:
    cfg, obs = _observe(ROBOTS, TARGETS)
    state = featurize(cfg, obs, FRAME9D)[0, 0]
    # distance 100; furthest at (50 along x, 120 along y), present; robot (0, -60), present; nearest shared.
    np.testing.assert_allclose(state, [100.0, 50.0, 120.0, 1.0, 0.0, -60.0, 1.0, 1.0, 0.0], atol=1e-4)
    # The scene seen in a mirror (x -> -x) gives the same state.
    cfg, obs = _observe([(0.0, 0.0), (-60.0, 0.0)], MIRRORED)
    np.testing.assert_allclose(featurize(cfg, obs, FRAME9D)[0, 0], state, atol=1e-4)
    # The whole scene turned by 90° about robot 0 gives robot 0 the same state.
    turn = np.array([[0.0, -1.0], [1.0, 0.0]])
    cfg, obs = _observe([tuple(turn @ p) for p in ROBOTS], [tuple(turn @ p) for p in TARGETS])
    np.testing.assert_allclose(featurize(cfg, obs, FRAME9D)[0, 0], state, atol=1e-4)


def test_present10d_zeroes_absent_pairs_and_flags_them() -> None:
    cfg, obs = _observe(ROBOTS, TARGETS)
    np.testing.assert_allclose(
        featurize(cfg, obs, STATE["present10d"])[0, 0], [0, 100, -120, 50, 1, 60, 0, 1, 1, 0], atol=1e-4
    )
    # One target in view and no robot: the furthest and the robot pairs are (0, 0) and flagged absent.
    cfg, obs = _observe([(0.0, 0.0), (-900.0, 0.0)], [(30.0, 40.0)])
    np.testing.assert_allclose(
        featurize(cfg, obs, STATE["present10d"])[0, 0], [30, 40, 0, 0, 0, 0, 0, 0, 0, 0], atol=1e-4
    )
    np.testing.assert_allclose(featurize(cfg, obs, FRAME9D)[0, 0], [50, 0, 0, 0, 0, 0, 0, 0, 0], atol=1e-4)


def test_relative_moves_are_named_from_the_nearest_target_and_the_furthests_side() -> None:
    cfg, obs = _observe(ROBOTS, TARGETS)
    moves = ACTION_SETS["relative"]
    frame = moves.frame(obs)
    names = list(moves.moves)
    velocity = {name: moves.velocity(cfg, np.full((1, 2), names.index(name)), frame)[0, 0] for name in names}
    np.testing.assert_allclose(velocity["toward"], [0.0, SPEED], atol=1e-12)
    np.testing.assert_allclose(velocity["left"], [-SPEED, 0.0], atol=1e-12)  # towards the furthest target's side
    np.testing.assert_allclose(velocity["away"], [0.0, -SPEED], atol=1e-12)
    np.testing.assert_allclose(velocity["toward-left"], [-SPEED / np.sqrt(2), SPEED / np.sqrt(2)], atol=1e-12)
    # Compass moves ignore the frame: N is +y whatever the robot sees.
    compass = ACTION_SETS["compass"]
    north = compass.velocity(cfg, np.zeros((1, 2), int), compass.frame(obs))[0, 0]
    np.testing.assert_allclose(north, [0, SPEED], atol=1e-12)


def test_law_moves_are_named_from_the_force_laws_pull_and_mirror_with_the_scene() -> None:
    # Robot 0: robot 1 watches the nearest target too, so it pulls nothing (weight 0); the furthest (-120, 50),
    # d = 130, pulls (130 - 10) / 140 along its direction; robot 1 at d = 60 < dr1 pushes with -1.
    cfg, obs = _observe(ROBOTS, TARGETS)
    moves = ACTION_SETS["law"]
    pull = (120.0 / 140.0) * np.array([-120.0, 50.0]) / 130.0 + np.array([-1.0, 0.0])
    x = pull / np.linalg.norm(pull)
    frame = moves.frame(obs)
    np.testing.assert_allclose(frame[0, 0], [x, [-x[1], x[0]]], atol=1e-9)  # y: a quarter turn counter-clockwise
    names = list(moves.moves)
    law = moves.velocity(cfg, np.full((1, 2), names.index("law")), frame)[0, 0]
    np.testing.assert_allclose(law, SPEED * x, atol=1e-9)
    # The scene in a mirror (x -> -x): the pull is mirrored, and so is the frame's y axis (the target frame's is), so
    # every move is the mirror image of the same move in the scene.
    cfg, obs = _observe([(0.0, 0.0), (-60.0, 0.0)], MIRRORED)
    mirrored = moves.frame(obs)[0, 0]
    np.testing.assert_allclose(mirrored, [[-x[0], x[1]], [x[1], x[0]]], atol=1e-9)
    for name in names:
        index = np.full((1, 2), names.index(name))
        here = moves.velocity(cfg, index, frame)[0, 0]
        np.testing.assert_allclose(moves.velocity(cfg, index, moves.frame(obs))[0, 0], [-here[0], here[1]], atol=1e-9)


def test_the_law_move_is_the_state_force_laws_move_wherever_it_pulls_and_the_target_frame_elsewhere() -> None:
    from sim import reset
    from sim.controllers import HAND_MADE

    cfg = scenario()
    rng = np.random.default_rng(3)
    world = reset(cfg, 600, rng)
    obs = sense(cfg, world, rng)
    law = HAND_MADE["force-6d-shared"]
    velocity, _ = law.act(cfg, world, obs, law.init(cfg, world, rng), rng)
    # The law with every robot's heading turned a quarter: where it pulls, the move is unchanged.
    turned = np.stack([-velocity[..., 1], velocity[..., 0]], -1) / cfg.robot_speed
    pulls = np.all(np.isclose(law.act(cfg, world, obs, turned, rng)[0], velocity), -1)
    moves = ACTION_SETS["law"]
    frame = moves.frame(obs)
    follows = moves.velocity(cfg, np.zeros(obs.n_seen.shape, np.int64), frame)
    seen = obs.n_seen >= 1
    assert (seen & pulls).sum() > 800 and (seen & ~pulls).sum() > 100
    np.testing.assert_allclose(follows[seen & pulls], velocity[seen & pulls], atol=1e-5)
    np.testing.assert_allclose(frame[seen & ~pulls], target_frame(obs)[seen & ~pulls], atol=1e-12)


def _arenas_with_headings(seed: int):
    """600 random arenas of the default scenario, sensed, and a random unit search heading for every robot."""
    from sim import reset

    cfg = scenario()
    rng = np.random.default_rng(seed)
    world = reset(cfg, 600, rng)
    obs = sense(cfg, world, rng)
    angle = rng.uniform(0.0, 2.0 * np.pi, obs.n_seen.shape)
    return cfg, world, obs, np.stack([np.cos(angle), np.sin(angle)], -1), rng


def test_law_search_moves_follow_the_law_where_it_pulls_and_the_search_heading_where_it_does_not() -> None:
    from sim.controllers import HAND_MADE

    cfg, world, obs, heading, rng = _arenas_with_headings(3)
    search = ACTION_SETS["law-search"]
    with pytest.raises(ValueError, match="search heading"):
        search.frame(obs)
    frame = search.frame(obs, heading)
    law = ACTION_SETS["law"].frame(obs)
    target = target_frame(obs)
    # Where the force law pulls, its move does not depend on the heading it is given: the two sets name the same
    # moves there.
    force = HAND_MADE["force-6d-shared"]
    pulls = np.all(
        np.isclose(force.act(cfg, world, obs, heading, rng)[0], force.act(cfg, world, obs, -heading, rng)[0]), -1
    )
    watched = (obs.n_seen >= 1) & ~pulls
    assert pulls.sum() > 500 and watched.sum() > 50
    np.testing.assert_array_equal(frame[pulls], law[pulls])
    # Elsewhere x is the heading, y its quarter turn, mirrored as the target frame is: the move "law" is the search.
    x = heading[~pulls]
    turned = np.stack([-x[:, 1], x[:, 0]], -1)
    mirrored = np.sign(
        np.einsum("nk,nk->n", target[~pulls][:, 1], np.stack([-target[~pulls][:, 0, 1], target[~pulls][:, 0, 0]], -1))
    )
    assert (mirrored < 0).any() and (mirrored > 0).any()
    np.testing.assert_allclose(frame[~pulls][:, 0], x, atol=1e-12)
    np.testing.assert_allclose(frame[~pulls][:, 1], turned * mirrored[:, None], atol=1e-12)
    follows = search.velocity(cfg, np.zeros(obs.n_seen.shape, np.int64), frame)
    np.testing.assert_allclose(follows[~pulls], SPEED * x, atol=1e-9)


@pytest.mark.parametrize("actions", ["compass", "relative"])
def test_a_relative_move_is_held_in_the_frame_it_was_chosen_in(actions: str) -> None:
    # The learner at the origin sees one target at (0, 100) moving east at 5 per step. "toward" (index 0, like N)
    # moves it due north for the whole 5-step action though the target drifts east: the frame is fixed when the
    # robot decides. Robot 1 is far away and does not learn.
    cfg = scenario(n_robots=2, n_targets=1)
    rng = np.random.default_rng(0)
    formulation = Formulation.of("frame9d", "difference", actions)
    state = reset_trial(cfg, 1, np.array([True, False]), formulation, rng)
    world = _world([(0.0, 0.0), (-900.0, 0.0)], [(0.0, 100.0)], vel=[(5.0, 0.0)])
    obs = sense(cfg, world)
    frame = formulation.actions.frame(obs)
    features = featurize(cfg, obs, FRAME9D)
    state = dataclasses.replace(
        state, world=world, obs=obs, view=obs, features=features, start_features=features, frame=frame
    )
    decide = np.ones((1, 2), bool)
    for _ in range(cfg.action_steps):
        state, out = step_trial(cfg, state, np.zeros((1, 2), np.int64), decide, rng)
        decide = out.decide
    np.testing.assert_allclose(state.world.robot_pos[0, 0], [0.0, cfg.action_steps * SPEED], atol=1e-9)
    assert out.boundary[0, 0]


def test_frame9d_keeps_lengths_puts_the_furthest_on_the_left_and_flags_presence_on_random_arenas() -> None:
    from sim import reset

    cfg = scenario()
    obs = sense(cfg, reset(cfg, 200, np.random.default_rng(5)))
    state = featurize(cfg, obs, FRAME9D).astype(np.float64)
    f = obs.features.astype(np.float64)
    sees, two, robot = obs.n_seen >= 1, obs.n_seen >= 2, obs.sees_robot
    np.testing.assert_allclose(state[..., 0], np.where(sees, np.linalg.norm(f[..., 0:2], axis=-1), 0.0), atol=1e-3)
    np.testing.assert_allclose(
        np.linalg.norm(state[..., 1:3], axis=-1), np.where(two, np.linalg.norm(f[..., 2:4], axis=-1), 0.0), atol=1e-3
    )
    np.testing.assert_allclose(
        np.linalg.norm(state[..., 4:6], axis=-1), np.where(robot, np.linalg.norm(f[..., 4:6], axis=-1), 0.0), atol=1e-3
    )
    assert (state[..., 2][two] >= 0).all()  # the furthest target on the frame's left (+y) side
    np.testing.assert_array_equal(state[..., 3], two)
    np.testing.assert_array_equal(state[..., 6], robot)
    np.testing.assert_array_equal(state[..., 7:9], obs.shared)
    assert two.sum() > 20 and robot.sum() > 20  # the arenas exercise every case


def test_law_track_heading_turns_to_the_pull_where_the_law_pulls_and_is_kept_where_it_does_not() -> None:
    from sim.actions import law_force

    cfg, world, obs, heading, _ = _arenas_with_headings(5)
    force = law_force(obs)
    norm = np.linalg.norm(force, axis=-1)
    pulls = norm > 1e-12
    assert pulls.sum() > 500 and (~pulls).sum() > 500
    track, search = ACTION_SETS["law-track"], ACTION_SETS["law-search"]
    kept = search.steer(cfg, world, obs, heading)
    turned = track.steer(cfg, world, obs, heading)
    # Where the law pulls the heading is its pull; elsewhere both sets keep it (reflected off the wall alike).
    np.testing.assert_allclose(turned[pulls], force[pulls] / norm[pulls][:, None], atol=1e-12)
    np.testing.assert_array_equal(turned[~pulls], kept[~pulls])
    assert not np.allclose(kept[pulls], turned[pulls])
    # law-search's heading never follows the law: only the wall turns it.
    inside = np.linalg.norm(world.robot_pos, axis=-1) < cfg.arena_radius - 1.0
    np.testing.assert_array_equal(kept[inside], heading[inside])


def _law_everywhere(actions: str, m: int):
    """A policy on the default state whose table picks the move ``law`` in every state, deciding every step."""
    from algorithm.discretization import Discretization
    from algorithm.policy import Policy
    from sim.formulation import FORMULATIONS

    formulation = FORMULATIONS["frame-recall-law"].replace(actions=actions)
    disc = Discretization.from_per_action([np.zeros((1, formulation.dim))] * 8)
    tables = np.zeros((1, disc.size), np.float32)
    tables[0, disc.offsets[0]] = 1.0
    return Policy(formulation, disc, tables, robot_table=np.zeros(m, np.int64), action_steps=1)


def test_the_move_law_of_law_track_is_the_hand_made_law_trial_for_trial() -> None:
    # The hand-made law on the learned state's information (force-recall) keeps its last pull's heading where it
    # pulls nowhere; a law-track table that always picks "law" moves exactly as it does, search included, so the two
    # cover the same targets at every step of every trial. law-search's "law" searches along a random heading.
    from algorithm.policy import PolicyController
    from sim.controllers import HAND_MADE
    from sim.rollout import evaluate

    cfg = scenario()
    hand = evaluate(cfg, HAND_MADE["force-recall"], 12, 400, seed=11)
    track = evaluate(cfg, PolicyController(_law_everywhere("law-track", cfg.n_robots)), 12, 400, seed=11)
    search = evaluate(cfg, PolicyController(_law_everywhere("law-search", cfg.n_robots)), 12, 400, seed=11)
    np.testing.assert_array_equal(track.coverage_per_trial, hand.coverage_per_trial)
    assert not np.array_equal(search.coverage_per_trial, hand.coverage_per_trial)


def test_a_target_beyond_every_robots_range_does_not_turn_the_law_track_heading() -> None:
    # Robot 0 at the origin, robot 1 far away, the only target 151 away from robot 0: nobody senses it, so the law
    # pulls nowhere and the search heading keeps its course; at 149 the same target turns it towards itself.
    track = ACTION_SETS["law-track"]
    heading = np.array([[[1.0, 0.0], [1.0, 0.0]]])
    for distance, want in ((151.0, [1.0, 0.0]), (149.0, [0.0, 1.0])):
        cfg, obs = _observe([(0.0, 0.0), (-600.0, 0.0)], [(0.0, distance)])
        steered = track.steer(cfg, _world([(0.0, 0.0), (-600.0, 0.0)], [(0.0, distance)]), obs, heading)
        np.testing.assert_allclose(steered[0, 0], want, atol=1e-12)
