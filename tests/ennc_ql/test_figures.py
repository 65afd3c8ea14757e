"""``policy.png``'s move map: the greedy move over a grid of states, computed without pixels and drawn for every
state definition."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from ennc_ql.figures import NEAREST_FRACTION, move_map, policy_figure
from sim import Formulation, scenario
from sim.features import FEATURIZER_REGISTRY

CFG = scenario()
M = CFG.mask_value


def codebook_policy(
    formulation: Formulation, codebook: list[list[float]], best: list[int], scale: list[float]
) -> Policy:
    """One table row, every action on ``codebook`` (a VQQL codebook): in the cell of codeword k, action ``best[k]``
    is worth 1 and every other 0."""
    disc = Discretization.from_per_action([np.array(codebook)] * 8, scale=np.array(scale))
    table = np.zeros((8, len(codebook)), np.float32)
    table[best, np.arange(len(codebook))] = 1.0
    return Policy(formulation, disc, tables=table.reshape(1, -1), robot_table=np.zeros(CFG.n_robots, np.int64))


def test_world_frame_map_points_each_compass_move_at_the_target() -> None:
    # The target due east, north, west or south of the robot, N, E, S, W being actions 0, 2, 4, 6; within 50 of it
    # in x and y (nearer the codeword at the robot than to the others: where the states are scaled once) NE (1).
    codebook = [[100, 0, 100, 0, M, M], [0, 100, 0, 100, M, M], [-100, 0, -100, 0, M, M], [0, -100, 0, -100, M, M]]
    codebook.append([0, 0, 0, 0, M, M])
    policy = codebook_policy(Formulation.of("collab6d", "paper", "compass"), codebook, [2, 0, 6, 4, 1], [50.0] * 6)
    grid = move_map(policy, CFG, cells=40)
    assert grid.moves.shape == (1, 40, 40) and grid.nearest is None and len(grid.panels) == 1
    x, y = np.meshgrid(grid.xs, grid.ys)
    inside = np.hypot(x, y) <= CFG.sensing_range
    near = np.maximum(np.abs(x), np.abs(y)) < 50
    expected = np.select([near, x > np.abs(y), y > np.abs(x), -x > np.abs(y)], [1, 2, 0, 6], 4)
    off_diagonal = inside & ~np.isclose(np.abs(x), np.abs(y))  # on a diagonal two codewords tie
    assert (grid.moves[0][off_diagonal] == expected[off_diagonal]).all()
    assert set(np.unique(grid.moves[0][inside])) == {0, 1, 2, 4, 6} and (grid.moves[0][~inside] == -1).all()


def test_target_frame_map_has_one_panel_per_shared_flags_with_that_panel_s_moves() -> None:
    # frame9d: (nearest distance, second's x, y, present, robot x, y, present, nearest shared, second shared). The
    # shared flags weigh 1000 per unit, so each panel's states fall on its own codewords; the unshared panel splits
    # at x = 0 between toward (0) and away (4), the others take right (6), away-left (3) and left (2).
    d = NEAREST_FRACTION * CFG.sensing_range
    codebook = [
        [d, 100, 50, 1, 0, 0, 0, 0, 0],
        [d, -100, 50, 1, 0, 0, 0, 0, 0],
        [d, 0, 100, 1, 0, 0, 0, 1, 0],
        [d, 0, 100, 1, 0, 0, 0, 0, 1],
        [d, 0, 100, 1, 0, 0, 0, 1, 1],
    ]
    scale = [30.0, 30.0, 30.0, 1.0, 30.0, 30.0, 1.0, 1e-3, 1e-3]
    policy = codebook_policy(Formulation.of("frame9d", "paper", "relative"), codebook, [0, 4, 6, 3, 2], scale)
    grid = move_map(policy, CFG, cells=40)
    assert grid.moves.shape == (4, 20, 40) and grid.nearest == d
    assert grid.panels[1:] == (
        "a teammate observes the nearest",
        "a teammate observes the second",
        "a teammate observes both",
    )
    x, y = np.meshgrid(grid.xs, grid.ys)
    drawn = (np.hypot(x, y) <= CFG.sensing_range) & (np.hypot(x, y) >= d) & (y > 0)
    assert drawn.any() and (grid.moves[:, ~drawn] == -1).all()
    unshared = grid.moves[0]
    assert (unshared[drawn & (x > 0)] == 0).all() and (unshared[drawn & (x < 0)] == 4).all()
    for panel, move in zip(grid.moves[1:], [6, 3, 2], strict=True):
        assert (panel[drawn] == move).all()


def test_map_is_read_from_the_named_robot_s_table_row() -> None:
    codebook = [[100, 0, 100, 0, M, M]]
    policy = codebook_policy(Formulation.of("collab6d", "paper", "compass"), codebook, [2], [50.0] * 6)
    tables = np.concatenate([policy.tables, np.roll(policy.tables, 3, axis=1)])
    two_rows = Policy(policy.formulation, policy.discretization, tables, robot_table=np.array([0, 1]))
    assert set(np.unique(move_map(two_rows, CFG, robot=0, cells=10).moves)) == {-1, 2}
    assert set(np.unique(move_map(two_rows, CFG, robot=1, cells=10).moves)) == {-1, 5}


PANELS = {"local2d": 1, "collab6d": 1, "shared8d": 2, "present10d": 2, "frame7d": 4, "frame9d": 4, "frame11d-recall": 4}


@pytest.mark.parametrize("name", sorted(FEATURIZER_REGISTRY))
def test_every_featurizer_draws_a_figure_with_its_move_map(name: str, tmp_path: Path) -> None:
    featurizer = FEATURIZER_REGISTRY[name]
    rng = np.random.default_rng(0)
    protos = [rng.normal(0.0, 80.0, (5, featurizer.dim)) for _ in range(8)]
    disc = Discretization.from_per_action(protos, scale=np.full(featurizer.dim, 50.0))
    actions = "relative" if featurizer.frame == "target" else "compass"
    policy = Policy(
        Formulation.of(name, "paper", actions),
        disc,
        tables=rng.normal(size=(2, disc.size)).astype(np.float32),
        robot_table=np.arange(CFG.n_robots) % 2,
    )
    grid = move_map(policy, CFG, cells=20)
    assert len(grid.panels) == PANELS[name] == grid.moves.shape[0]
    assert (grid.moves >= 0).any() and grid.moves.max() < 8
    out = policy_figure(policy, CFG, tmp_path / "policy.png", step=10)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
