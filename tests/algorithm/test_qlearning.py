"""Discretizations, tabular Q-learning (phase 2) and ENNC-QL phase 1 on small problems with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from algorithm.discretization import Discretization, nearest
from algorithm.phase1 import Phase1Config, phase1, to_classes
from algorithm.qtable import merge_increments, n_step_targets, q_targets, q_update, row_best
from algorithm.transitions import Transitions

GAMMA = 0.9


def test_nearest_matches_brute_force_and_breaks_ties_low() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(500, 3))
    protos = rng.normal(size=(17, 3))
    brute = np.argmin(((points[:, None, :] - protos[None]) ** 2).sum(-1), axis=1)
    np.testing.assert_array_equal(nearest(points, protos), brute)
    assert nearest(np.array([[0.5]]), np.array([[0.0], [1.0]]))[0] == 0


def test_cells_are_global_per_action_and_respect_the_scale() -> None:
    disc = Discretization.from_per_action(
        [np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[0.0, 0.0], [0.0, 10.0], [0.0, 20.0]])]
    )
    cells = disc.cells(np.array([[9.0, 1.0], [0.0, 16.0]]))
    np.testing.assert_array_equal(cells, [[1, 2], [0, 4]])
    assert disc.size == 5 and disc.n_actions == 2 and list(disc.sizes()) == [2, 3]
    # (9, 1) is nearer (10, 5) in plain Euclidean terms, but nearer (0, 0) once y differences weigh 10x.
    two = Discretization.from_per_action([np.array([[0.0, 0.0], [10.0, 5.0]])])
    weighted = Discretization(two.prototypes, two.labels, two.offsets, scale=np.array([1.0, 0.1], np.float32))
    assert two.cells(np.array([[9.0, 1.0]]))[0, 0] == 1
    assert weighted.cells(np.array([[9.0, 1.0]]))[0, 0] == 0


def test_shared_codebook_gives_the_same_cell_for_every_action() -> None:
    codebook = np.random.default_rng(1).normal(size=(8, 6))
    disc = Discretization.shared(codebook, 8)
    assert disc.is_shared()
    states = np.random.default_rng(2).normal(size=(100, 6))
    cells = disc.cells(states)
    np.testing.assert_array_equal(cells - disc.offsets[:-1], np.repeat(nearest(states, codebook)[:, None], 8, 1))


def test_carry_over_inherits_the_nearest_old_value() -> None:
    old = Discretization.from_per_action([np.array([[0.0], [10.0]]), np.array([[5.0]])])
    table = np.array([[1.0, 2.0, 3.0]])
    new = Discretization.from_per_action([np.array([[1.0], [9.0], [12.0]]), np.array([[0.0], [7.0]])])
    np.testing.assert_array_equal(new.carry_over(old, table), [[1.0, 2.0, 2.0, 3.0, 3.0]])


def test_discretization_rejects_inconsistent_arrays() -> None:
    with pytest.raises(ValueError, match="offsets"):
        Discretization(np.zeros((3, 2), np.float32), np.zeros(3, np.float32), np.array([0, 3, 3]))
    with pytest.raises(ValueError, match="finite"):
        Discretization(np.full((1, 2), np.nan, np.float32), np.zeros(1, np.float32), np.array([0, 1]))


def test_single_q_update_is_equation_1() -> None:
    table = np.array([0.5, 2.0])
    visits = np.zeros(2, np.uint64)
    q_update(table, visits, np.array([0]), np.array([1.5]), alpha=0.1)
    assert table[0] == pytest.approx(0.9 * 0.5 + 0.1 * 1.5)
    assert table[1] == 2.0
    np.testing.assert_array_equal(visits, [1, 0])


def test_repeated_hits_in_a_batch_equal_sequential_updates_with_the_mean_target() -> None:
    table = np.array([0.0])
    visits = np.zeros(1, np.uint64)
    q_update(table, visits, np.array([0, 0, 0]), np.array([1.0, 1.0, 1.0]), alpha=0.5)
    assert table[0] == pytest.approx(1 - 0.5**3)  # three sequential updates towards 1
    assert visits[0] == 3


def test_tabular_q_learning_converges_to_known_values_on_a_chain() -> None:
    # States 0..3 on a line, actions 0 = left, 1 = right; reaching 3 ends the episode with reward 1.
    # One cell per (state, action): Q*(s, right) = γ^(2−s); Q*(s, left) = γ·V*(max(s−1, 0)).
    disc = Discretization.from_per_action([np.arange(3.0)[:, None]] * 2)
    table = np.zeros(disc.size)
    visits = np.zeros(disc.size, np.uint64)
    rng = np.random.default_rng(0)
    for _ in range(3000):
        s = rng.integers(0, 3, 64)
        a = rng.integers(0, 2, 64)
        nxt = np.where(a == 1, s + 1, np.maximum(s - 1, 0))
        done = nxt == 3
        reward = done.astype(float)
        next_cells = disc.cells(np.minimum(nxt, 2)[:, None].astype(float))
        targets = q_targets(table[next_cells].max(axis=1), reward, done, GAMMA)
        q_update(table, visits, disc.cells(s[:, None].astype(float))[np.arange(64), a], targets, alpha=0.2)
    v = np.array([GAMMA**2, GAMMA, 1.0])
    right = v
    left = GAMMA * v[[0, 0, 1]]
    np.testing.assert_allclose(table, np.concatenate([left, right]), atol=1e-3)
    assert (row_best(table[None], np.zeros(3, np.int64), disc.cells(np.arange(3.0)[:, None]))[1] == 1).all()


def test_merge_adds_the_visit_weighted_mean_of_the_changes() -> None:
    tables = np.array([[1.0, 1.0, 1.0], [5.0, 5.0, 5.0]])
    visits = np.array([[1, 0, 0], [0, 0, 0]], np.uint64)
    increments = [
        (0, np.array([2.0, 1.0, 0.0]), np.array([2, 1, 0])),
        (0, np.array([4.0, 0.0, 0.0]), np.array([6, 0, 0])),
    ]
    merged, total = merge_increments(tables, visits, increments)
    # Cell 0: changes 2 over 2 visits and 4 over 6 visits -> (2*2 + 4*6) / 8 = 3.5; unvisited cells keep their value.
    np.testing.assert_allclose(merged, [[4.5, 2.0, 1.0], [5.0, 5.0, 5.0]])
    np.testing.assert_array_equal(total, [[9, 1, 0], [0, 0, 0]])
    assert tables[0, 0] == 1.0 and visits[0, 0] == 1  # pure: the inputs are untouched


def test_to_classes_keeps_few_values_and_bins_many() -> None:
    config = Phase1Config(max_classes=4)
    q = np.array([0.0, 0.9, 0.9, 1.0 + 1e-9, 1.0])
    np.testing.assert_allclose(to_classes(q, config), [0.0, 0.9, 0.9, 1.0, 1.0])
    many = np.linspace(0.0, 1.0, 101)
    classes = to_classes(many, config)
    assert np.unique(classes).size == 4
    # Each bin is labelled by the mean of its members, so order is kept and the overall mean is preserved.
    assert np.all(np.diff(classes) >= 0)
    assert classes.mean() == pytest.approx(many.mean(), abs=1e-6)


def chain_transitions(copies: int, rng: np.random.Generator) -> Transitions:
    s = np.repeat(np.arange(3), copies * 2)
    a = np.tile(np.repeat([0, 1], copies), 3)
    nxt = np.where(a == 1, s + 1, np.maximum(s - 1, 0))
    done = nxt == 3
    state = (s[:, None] * 10.0 + rng.normal(0, 0.5, (s.size, 1))).astype(np.float32)
    next_state = (np.minimum(nxt, 2)[:, None] * 10.0 + rng.normal(0, 0.5, (s.size, 1))).astype(np.float32)
    return Transitions(
        robot=np.zeros(s.size, np.int16),
        state=state,
        action=a.astype(np.uint8),
        reward=done.astype(np.float32),
        next_state=next_state,
        done=done,
    )


def test_phase1_iterations_recover_the_q_values_of_a_deterministic_chain() -> None:
    data = chain_transitions(40, np.random.default_rng(0))
    result = phase1(data, n_actions=2, config=Phase1Config(n_cycles=60, max_iterations=10), seed=0)
    assert result.converged
    assert result.iterations <= 6  # values propagate one step per iteration, then stop changing
    cells = result.discretization.cells(np.array([[0.0], [10.0], [20.0]]))
    values = result.discretization.labels[cells]
    v = np.array([GAMMA**2, GAMMA, 1.0])
    np.testing.assert_allclose(values[:, 1], v, atol=1e-5)
    np.testing.assert_allclose(values[:, 0], GAMMA * v[[0, 0, 1]], atol=1e-5)
    assert result.changed[-1] == 0.0 and result.changed[0] > 0.0


def test_phase1_one_iteration_separates_the_negative_region() -> None:
    # One action; states left of 0 end with −1, the rest continue with q = 0 [paper: one iteration suffices].
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, (2000, 2)).astype(np.float32)
    bad = x[:, 0] < 0
    data = Transitions(
        robot=np.zeros(2000, np.int16),
        state=x,
        action=np.zeros(2000, np.uint8),
        reward=np.where(bad, -1.0, 0.0).astype(np.float32),
        next_state=x,
        done=bad,
    )
    result = phase1(data, n_actions=1, config=Phase1Config(n_cycles=80, max_iterations=1), seed=3)
    disc = result.discretization
    predicted = disc.labels[disc.cells(x)[:, 0]]
    assert np.mean(predicted == np.where(bad, -1.0, 0.0)) > 0.9
    assert set(np.unique(disc.labels)) == {-1.0, 0.0}
    assert disc.scale is not None  # fitted on standardized states


def test_phase1_rejects_empty_and_out_of_range_data() -> None:
    with pytest.raises(ValueError, match="at least one"):
        phase1(Transitions.empty(2), n_actions=2)
    data = chain_transitions(2, np.random.default_rng(0))
    with pytest.raises(ValueError, match="actions"):
        phase1(data, n_actions=1)


def test_a_decaying_step_size_is_the_running_mean_of_the_targets_down_to_its_floor() -> None:
    # alpha = 1: the initial value weighs nothing, so each update is the mean of the targets so far, however they
    # are batched; past 1 / floor = 4 visits the step stays at the floor.
    rng = np.random.default_rng(0)
    targets = rng.normal(size=12)
    table, visits = np.array([7.0]), np.zeros(1, np.uint64)
    for i, t in enumerate(targets[:4]):
        q_update(table, visits, np.array([0]), np.array([t]), alpha=1.0, alpha_floor=0.25)
        assert table[0] == pytest.approx(targets[: i + 1].mean())
    expected = targets[:4].mean()
    for t in targets[4:]:
        expected += 0.25 * (t - expected)
        q_update(table, visits, np.array([0]), np.array([t]), alpha=1.0, alpha_floor=0.25)
    assert table[0] == pytest.approx(expected)
    # One batch of 3 hits at visits 0: the mean of the three, as three sequential running-mean steps give.
    batch, visits = np.array([7.0]), np.zeros(1, np.uint64)
    q_update(batch, visits, np.zeros(3, int), targets[:3], alpha=1.0, alpha_floor=0.25)
    assert batch[0] == pytest.approx(targets[:3].mean())
    # alpha = 0.1: the initial value weighs 9 samples; the 10th step is 1 / 10, then 1 / 11, ...
    table, visits = np.array([0.0]), np.zeros(1, np.uint64)
    q_update(table, visits, np.zeros(2, int), np.array([1.0, 1.0]), alpha=0.1, alpha_floor=0.01)
    assert table[0] == pytest.approx(2 / 11)


def test_phase1_bootstraps_from_learned_values_of_a_warm_start() -> None:
    # One action, every tuple a 0-reward step into a state near the second warm prototype, whose learned value is
    # 5: the targets are γ·5 with the learned values, 0 with Q̂^(0) ≡ 0 (the paper's first iteration).
    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 1, (400, 2)).astype(np.float32)
    data = Transitions(
        robot=np.zeros(400, np.int16),
        state=x,
        action=np.zeros(400, np.uint8),
        reward=np.zeros(400, np.float32),
        next_state=np.full((400, 2), 0.9, np.float32),
        done=np.zeros(400, bool),
    )
    warm = Discretization.from_per_action([np.array([[-0.9, -0.9], [0.9, 0.9]])], [np.array([0.0, 0.0])])
    config = Phase1Config(n_cycles=20, max_iterations=1, standardize=False)
    learned = phase1(data, 1, config, seed=0, warm_start=warm, values=np.array([-3.0, 5.0]))
    np.testing.assert_allclose(learned.discretization.labels, GAMMA * 5.0, rtol=1e-6)
    plain = phase1(data, 1, config, seed=0, warm_start=warm)
    np.testing.assert_allclose(plain.discretization.labels, 0.0)
    with pytest.raises(ValueError, match="warm start"):
        phase1(data, 1, config, values=np.array([1.0, 2.0]))


def test_seeded_phase1_starts_from_training_states_and_keeps_them_where_classes_are_pure() -> None:
    # One class everywhere: ENNC from one prototype has nothing to split and stays at one; seeded with 20 of the
    # training states it keeps them (each region pure, each pulling its share of the patterns), at their centroids.
    rng = np.random.default_rng(4)
    x = rng.uniform(-1, 1, (1000, 2)).astype(np.float32)
    data = Transitions(
        robot=np.zeros(1000, np.int16),
        state=x,
        action=np.zeros(1000, np.uint8),
        reward=np.zeros(1000, np.float32),
        next_state=x,
        done=np.ones(1000, bool),
    )
    plain = phase1(data, 1, Phase1Config(n_cycles=20, max_iterations=1), seed=0)
    seeded = phase1(data, 1, Phase1Config(n_cycles=20, max_iterations=1, seed_prototypes=20), seed=0)
    assert plain.discretization.size == 1
    assert seeded.discretization.size == 20
    cells = seeded.discretization.cells(x)[:, 0]
    assert np.bincount(cells, minlength=20).min() > 0  # every seeded cell holds training states


def test_phase1_can_draw_its_classes_from_the_lost_signal_alone() -> None:
    # Per-decision rewards 0.2 … 2.0 everywhere, −1 where the tuple lost every target (x < 0): the reward's own
    # classes are many; the lost signal gives exactly two, −1 left of 0 and 0 right of it. Right of 0 some tuples
    # end at the time-out with a reward of −1 too (Eq. 2's one target and a robot in view): the lost signal is what
    # s′ shows, not the reward's value, so they stay 0.
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, (2000, 2)).astype(np.float32)
    bad = x[:, 0] < 0
    timed_out = ~bad & (rng.random(2000) < 0.1)
    data = Transitions(
        robot=np.zeros(2000, np.int16),
        state=x,
        action=np.zeros(2000, np.uint8),
        reward=np.where(bad | timed_out, -1.0, rng.integers(1, 11, 2000) / 5).astype(np.float32),
        next_state=x,
        done=bad | timed_out,
    )
    config = Phase1Config(n_cycles=80, max_iterations=1, targets="lost")
    with pytest.raises(ValueError, match="needs lost"):
        phase1(data, n_actions=1, config=config)
    disc = phase1(data, n_actions=1, config=config, seed=3, lost=bad, lost_reward=-1.0).discretization
    assert set(np.unique(disc.labels)) == {-1.0, 0.0}
    predicted = disc.labels[disc.cells(x)[:, 0]]
    assert np.mean(predicted == np.where(bad, -1.0, 0.0)) > 0.9
    with pytest.raises(ValueError, match="targets"):
        Phase1Config(targets="money")  # type: ignore[arg-type]


def test_row_best_equals_numpy_max_and_argmax_with_ties_and_nans() -> None:
    rng = np.random.default_rng(5)
    tables = rng.integers(-2, 3, size=(4, 30)).astype(np.float64)  # small integers: many exact ties
    tables[1, 3] = tables[2, 7] = np.nan
    rows = rng.integers(0, 4, 500)
    cells = rng.integers(0, 30, size=(500, 8))
    cells[:5] = 3  # one cell for every action: an all-NaN row for table 1, all equal for the others
    gathered = tables[rows[:, None], cells]
    best, action = row_best(tables, rows, cells)
    np.testing.assert_array_equal(best, gathered.max(axis=1))
    np.testing.assert_array_equal(action, np.argmax(gathered, axis=1))
    assert np.isnan(best).any() and (action[:5] == 0).all()
    empty = row_best(tables, rows[:0], cells[:0])
    assert empty[0].shape == empty[1].shape == (0,)


def _n_step(n: int, tuples: list[tuple[int, int, float, float, bool, bool]], gamma: float = 0.5):
    """Feed ``tuples`` (trial row, cell, reward, bootstrap, ends, done) one call at a time; the targets completed."""
    queue_cells, queue_rewards, length = np.zeros((2, n), np.int64), np.zeros((2, n)), np.zeros(2, np.int64)
    done_targets = []
    for row, cell, reward, boot, ends, done in tuples:
        cells, targets = np.empty(n, np.int64), np.empty(n)
        k = n_step_targets(
            np.array([row]),
            np.array([cell]),
            np.array([reward]),
            np.array([boot]),
            np.array([ends]),
            np.array([done]),
            gamma,
            queue_cells,
            queue_rewards,
            length,
            cells,
            targets,
        )
        done_targets.append(sorted(zip(cells[:k].tolist(), targets[:k].tolist(), strict=True)))
    return done_targets


def test_n_step_targets_sum_the_next_rewards_and_bootstrap_after_n_decisions() -> None:
    # Robot 0 decides in cells 10, 11, 12, 13 (rewards 1, 2, 4, 8), γ = 0.5, n = 3: cell 10's target is known at
    # the third tuple, 1 + 0.5·2 + 0.25·4 + 0.125·max Q(s′) = 3 + 0.125·6; cell 11's at the fourth. Robot 1 is kept
    # apart. The time-out then cuts robot 0's trial: cells 12 and 13 get their shorter returns, bootstrapped.
    out = _n_step(
        3,
        [
            (0, 10, 1.0, 99.0, False, False),
            (1, 20, 5.0, 99.0, False, False),
            (0, 11, 2.0, 99.0, False, False),
            (0, 12, 4.0, 6.0, False, False),
            (0, 13, 8.0, 2.0, False, False),
            (0, 14, 16.0, 4.0, True, False),
        ],
    )
    assert out[:3] == [[], [], []]
    assert out[3] == [(10, 1.0 + 1.0 + 1.0 + 0.125 * 6.0)]
    assert out[4] == [(11, 2.0 + 2.0 + 2.0 + 0.125 * 2.0)]
    assert out[5] == [(12, 4.0 + 4.0 + 4.0 + 0.125 * 4.0), (13, 8.0 + 8.0 + 0.25 * 4.0), (14, 16.0 + 0.5 * 4.0)]


def test_a_terminal_tuple_cuts_every_held_return_without_a_bootstrap() -> None:
    out = _n_step(4, [(1, 5, 1.0, 50.0, False, False), (1, 6, -1.0, 50.0, True, True)])
    assert out == [[], [(5, 1.0 - 0.5), (6, -1.0)]]


def test_one_step_targets_through_the_queue_are_equation_1() -> None:
    rng = np.random.default_rng(3)
    n = 40
    rewards, boot = rng.normal(size=n), rng.normal(size=n)
    dones, ends = rng.random(n) < 0.3, rng.random(n) < 0.5
    ends |= dones
    cells, targets = np.empty(n, np.int64), np.empty(n)
    k = n_step_targets(
        np.arange(n),
        np.arange(n),
        rewards,
        boot,
        ends,
        dones,
        0.9,
        np.zeros((n, 1), np.int64),
        np.zeros((n, 1)),
        np.zeros(n, np.int64),
        cells,
        targets,
    )
    assert k == n
    np.testing.assert_array_equal(targets[np.argsort(cells)], q_targets(boot, rewards, dones, 0.9))
