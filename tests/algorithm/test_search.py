"""The nearest-prototype search of Discretization.cells against brute force, and the slice that shares its cells.

Brute force here is the definition: per action, the argmin of float64 squared distances Σ_k (x_k − c_k)², the lowest
index on a tie. The search must return exactly that, whatever the data: exact ties, duplicated prototypes, masked
states, one-prototype actions, shared codebooks, values far beyond the unit scale.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from algorithm._search import _group_rows, search_grid
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization, nearest
from algorithm.policy import Policy
from algorithm.transitions import Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from sim import FORMULATIONS, Formulation, scenario
from sim.trial import reset_trial, step_trial


def brute_cells(disc: Discretization, states: np.ndarray) -> np.ndarray:
    x = np.asarray(states)
    x = (x if disc.scale is None else x / disc.scale).astype(np.float64)
    out = np.empty((len(x), disc.n_actions), np.int64)
    for a in range(disc.n_actions):
        protos = disc._scaled(a).astype(np.float64)
        out[:, a] = disc.offsets[a] + np.argmin(((x[:, None, :] - protos[None]) ** 2).sum(axis=-1), axis=1)
    return out


@pytest.mark.parametrize("dim", [2, 6])
@pytest.mark.parametrize("seed", range(3))
def test_cells_equal_brute_force_and_the_matmul_search_on_random_data(dim: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    sizes = [1, 2, 17, 64, 65, 228, 301, 5]
    protos = [rng.normal(size=(s, dim)) for s in sizes]
    disc = Discretization.from_per_action(protos, scale=rng.uniform(0.5, 3.0, dim))
    states = rng.normal(scale=1.5, size=(700, dim)).astype(np.float32)
    cells = disc.cells(states)
    np.testing.assert_array_equal(cells, brute_cells(disc, states))
    scaled = states / disc.scale
    matmul = np.stack([disc.offsets[a] + nearest(scaled, disc._scaled(a)) for a in range(disc.n_actions)], axis=1)
    np.testing.assert_array_equal(cells, matmul)
    np.testing.assert_array_equal(disc.cells(states.astype(np.float64)), brute_cells(disc, states.astype(np.float64)))


def test_exact_ties_go_to_the_lowest_index() -> None:
    # Small integers: every distance is exact, so equidistant prototypes tie exactly, in float32 as in float64;
    # duplicates and ties land in different groups of the index, which are scanned in no particular order.
    rng = np.random.default_rng(7)
    grid = rng.integers(-3, 4, size=(400, 6)).astype(np.float32)
    duplicated = np.concatenate([grid, grid[::-1]])
    disc = Discretization.from_per_action([duplicated, grid[:3], np.repeat(grid[:1], 9, axis=0)])
    states = rng.integers(-4, 5, size=(2000, 6)).astype(np.float32)
    cells = disc.cells(states)
    np.testing.assert_array_equal(cells, brute_cells(disc, states))
    assert disc._search_index()[0].zero_sets >= 6  # states with a zero coordinate tie in fewer dimensions too
    assert (cells[:, 2] == disc.offsets[2]).all()  # nine identical prototypes: always the first
    midpoint = Discretization.from_per_action([np.array([[2.0], [0.0], [2.0]])])
    assert midpoint.cells(np.array([[1.0]]))[0, 0] == 0


def test_masked_states_large_values_and_shared_codebooks() -> None:
    rng = np.random.default_rng(3)
    mask = np.float32(1000.0)
    states = rng.uniform(-150, 150, size=(3000, 6)).astype(np.float32)
    states[rng.random(3000) < 0.4, 4:] = mask  # no robot in view
    states[rng.random(3000) < 0.05, :4] = mask  # no target in view
    protos = [states[rng.choice(3000, size, replace=False)] + rng.normal(0, 5, (size, 6)) for size in (250, 90, 1)]
    for scale in (None, np.array([64, 64, 69, 69, 502, 502], np.float32)):
        disc = Discretization.from_per_action(protos, scale=scale)
        np.testing.assert_array_equal(disc.cells(states), brute_cells(disc, states))
    shared = Discretization.shared(protos[0], 8)
    np.testing.assert_array_equal(shared.cells(states), brute_cells(shared, states))
    lone = np.where(np.arange(6) == 2, states, 0.0).astype(np.float32)  # all but one dimension 0: a grid index
    np.testing.assert_array_equal(shared.cells(lone), brute_cells(shared, lone))
    assert shared._search_index()[0].grids == 1
    huge = Discretization.from_per_action([np.array([[0.0, 0.0], [3e19, 0.0], [-3e19, 1.0]])])
    points = np.array([[2.9e19, 0.0], [-1e25, 0.0], [0.0, 1e-30]])
    np.testing.assert_array_equal(huge.cells(points), brute_cells(huge, points))


def test_the_index_cuts_at_presence_flags_and_still_equals_brute_force() -> None:
    # frame9d-like: three offsets whose absent pairs are zeroed, and two presence flags in {0, 1} whose gap is a
    # quarter of the offsets' range (scaled, a policy's flags span 2-3 where its offsets span 5-10); prototypes keep
    # the flags exact, as ENNC's do for a flag that separates its classes. No group may span a flag's gap: a box
    # from 0 to 1 in a flag bounds nothing for a state at either end.
    rng = np.random.default_rng(11)

    def frame_like(n: int) -> np.ndarray:
        x = rng.uniform(-2, 2, size=(n, 7))
        flags = rng.random((n, 2)) < 0.5
        x[~flags[:, 0], 1:3] = 0.0
        x[~flags[:, 1], 4:6] = 0.0
        x[:, 3], x[:, 6] = flags[:, 0], flags[:, 1]
        return x.astype(np.float32)

    protos = [frame_like(size) for size in (300, 140, 65)]
    states = frame_like(4000)
    scaled = Discretization.from_per_action(protos, scale=rng.uniform(0.3, 3.0, 7).astype(np.float32))
    np.testing.assert_array_equal(scaled.cells(states), brute_cells(scaled, states))
    disc = Discretization.from_per_action(protos)
    np.testing.assert_array_equal(disc.cells(states), brute_cells(disc, states))
    # Each flag fixes its dimension, on or off: both pairs present (5 free) or one (3 free), searched in fewer
    # dimensions; none (1 free), on a grid.
    for searcher in (scaled._search_index()[0], disc._search_index()[0]):
        assert (searcher.zero_sets, searcher.grids) == (3, 1)
    searcher = disc._search_index()[0]
    index = searcher.full
    real = index.index >= 0
    assert real.sum() == disc.size
    # Actions 0 and 1 (300 and 140 prototypes) hold every flag pattern more than GROUP / 4 times, so both flags are
    # cut before any median; action 2 (65) stops cutting once its two halves fit a group.
    groups = slice(int(index.groups[0]), int(index.groups[2]))
    for flag in (3, 6):
        values = np.where(real, index.points[:, :, flag], np.nan)[groups]
        assert (np.nanmin(values, axis=1) == np.nanmax(values, axis=1)).all()


@pytest.mark.parametrize("seed", range(3))
def test_states_fixed_in_all_dimensions_but_one_equal_brute_force_on_the_grid_index(seed: int) -> None:
    # Small integers in the free dimension and in the prototypes: distances are exact, so ties are exact too, and
    # states fall on the cells' edges; some states lie beyond the grid and go to the reduced index.
    rng = np.random.default_rng(seed)
    dim, free = 5, 2
    protos = [rng.integers(-3, 4, size=(size, dim)).astype(np.float32) for size in (1, 9, 70, 230)]
    protos[3][:40] = protos[3][40:80]  # duplicates
    protos[2][:, free] = rng.uniform(-30, 30, 70).astype(np.float32)
    disc = Discretization.from_per_action(protos)
    states = np.zeros((3000, dim), np.float32)
    states[:1000, free] = rng.integers(-12, 13, 1000)
    states[1000:2000, free] = rng.uniform(-40, 40, 1000)
    states[2000:, free] = rng.uniform(-1e4, 1e4, 1000)
    states = states[states[:, free] != 0]
    np.testing.assert_array_equal(disc.cells(states), brute_cells(disc, states))
    flags_on = states.copy()
    flags_on[:, np.arange(dim) != free] = 1.0  # the other dimensions at the flag value: a grid as well
    np.testing.assert_array_equal(disc.cells(flags_on), brute_cells(disc, flags_on))
    searcher = disc._search_index()[0]
    assert searcher.grids == 4  # 0 or 1 in the other dimensions; with 1 in the free one as well, a single cell
    grid = searcher._grids[int(np.int64(31) ^ (1 << free))]
    assert np.diff(grid.starts).min() >= 1
    far = states[np.abs(states[:, free]) > grid.edges[0, -1]]
    assert len(far) > 0 and (search_grid(grid, far) == -1).all()


def test_cells_reject_states_of_the_wrong_shape() -> None:
    disc = Discretization.from_per_action([np.zeros((2, 6))])
    with pytest.raises(ValueError, match="states must have shape"):
        disc.cells(np.zeros((3, 2)))


def reference_trial(sl: ExperienceSlice, agent: TabularAgent, update: bool) -> Transitions:
    """The slice's trial as it was written before its cells were shared: every use of a state's cells searches it
    again, by brute force. It calls the slice's own decision so that the random stream is the same, and runs the
    slice's formulation: its state, reward and action set."""
    cfg, sc = sl.cfg, sl.config
    until_change = sc.action_mode == "until_change"
    state = reset_trial(cfg, sc.n_arenas, sl.learner_mask, sc.formulation, sl.rng)
    robot_ids = np.broadcast_to(np.arange(cfg.n_robots), state.shape)
    decide = np.ones(state.shape, bool)
    cell_sa = np.zeros(state.shape, np.int64)
    disc, parts = agent.discretization, []
    while True:
        flat = state.features.reshape(-1, state.features.shape[-1])
        action, cell_sa = sl._decide(agent, state, decide, cell_sa, update, brute_cells(disc, flat))
        state, out = step_trial(cfg, state, action, decide, sl.rng, hold=sc.max_action_steps if until_change else None)
        cells = brute_cells(disc, state.features.reshape(-1, state.features.shape[-1])).reshape(*state.shape, -1)
        if until_change:
            out = out.with_boundary(np.take_along_axis(cells, out.action[..., None], axis=2)[..., 0] != cell_sa)
        emit = out.transition
        if emit.any():
            batch = Transitions(
                robot=robot_ids[emit].astype(np.int16),
                state=out.start_features[emit],
                action=out.action[emit].astype(np.uint8),
                reward=out.reward[emit],
                next_state=out.next_features[emit],
                done=out.done[emit],
            )
            parts.append(batch)
            if update:
                agent.update(robot_ids[emit], cell_sa[emit], cells[emit], batch.reward, batch.done)
        if out.trial_over:
            return Transitions.concat(parts) if parts else Transitions.empty(sc.formulation.dim)
        decide = out.decide


def explored_policy(action_mode: str) -> Policy:
    """A policy whose prototypes are explored states (so the search has real work), with random tables."""
    cfg = scenario()
    rng = np.random.default_rng(0)
    states = ExperienceSlice(cfg, SliceConfig(FORMULATIONS["paper"], n_arenas=64), seed=1).run_trial().state
    scale = states.std(axis=0).astype(np.float32)
    if action_mode == "until_change":
        disc = Discretization.shared(states[rng.choice(len(states), 120, replace=False)], 8)
        disc = dataclasses.replace(disc, scale=scale)
    else:
        picks = [states[rng.choice(len(states), size, replace=False)] for size in (80, 40, 150, 1, 60, 90, 70, 110)]
        disc = Discretization.from_per_action(picks, scale=scale)
    tables = rng.normal(size=(cfg.n_robots, disc.size)).astype(np.float32)
    return Policy(FORMULATIONS["paper"], disc, tables, np.arange(cfg.n_robots), action_mode=action_mode)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("action_mode", "learners", "reward", "actions"),
    [
        ("fixed", None, "eq2", "compass"),
        ("fixed", (0, 3, 7), "difference-decision", "relative"),
        ("until_change", None, "eq2", "compass"),
        ("until_change", (2,), "difference", "relative"),
    ],
)
def test_run_trial_gives_the_tuples_and_tables_of_the_reference_loop(
    action_mode: str, learners: tuple[int, ...] | None, reward: str, actions: str
) -> None:
    formulation = Formulation.of("collab6d", reward, actions)
    policy = dataclasses.replace(explored_policy(action_mode), formulation=formulation)
    config = SliceConfig(formulation, n_arenas=24, learning_robots=learners, action_mode=action_mode)  # type: ignore[arg-type]
    fast, slow = TabularAgent(policy, Phase2Config()), TabularAgent(policy, Phase2Config())
    fast_slice, slow_slice = ExperienceSlice(scenario(), config, seed=9), ExperienceSlice(scenario(), config, seed=9)
    for _ in range(2):
        got, want = fast_slice.run_trial(fast, update=True), reference_trial(slow_slice, slow, update=True)
        for name in ("robot", "state", "action", "reward", "next_state", "done"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    np.testing.assert_array_equal(fast.tables, slow.tables)
    np.testing.assert_array_equal(fast.visits, slow.visits)
    assert fast.visits.sum() > 0


@pytest.mark.parametrize("distinct", [1, 24, 5000])
def test_group_rows_partitions_the_rows_by_key_each_group_ascending(distinct: int) -> None:
    rng = np.random.default_rng(distinct)
    keys = rng.integers(0, 1 << 40, distinct)[rng.integers(0, distinct, 5000)]
    order, starts, group_keys = (np.empty(keys.size, np.int64) for _ in range(3))
    groups = _group_rows(keys, order, starts, group_keys)
    assert groups == np.unique(keys).size
    assert sorted(order.tolist()) == list(range(keys.size))
    bounds = [*starts[:groups].tolist(), keys.size]
    for g in range(groups):
        rows = order[bounds[g] : bounds[g + 1]]
        assert (keys[rows] == group_keys[g]).all() and (np.diff(rows) > 0).all()
    # Groups come in order of first appearance.
    assert (np.diff([int(np.flatnonzero(keys == k)[0]) for k in group_keys[:groups]]) > 0).all()
