"""Phase 1's prototypes and Q-value labels, bit for bit, for a fixed seed.

The cold digest below was produced by the phase-1 code of commit dfd376d, where ENNC took the Q classes themselves
as its targets: this file, run there, hashed the cold result of :func:`phase1_runs` with :func:`digest` (CPU,
torch 2.13.0). Phase 1 now hands ENNC class indices and maps each prototype's class back to its Q value; ENNC
keeps classes in sorted order either way, so its random decisions and therefore every prototype must stay the
same. The data cover both kinds of classes, distinct rounded q values (few enough) and quantile bins labelled by
their mean (too many), non-integer Q values, an action without tuples, and subsampling.

The warm start (float32 labels mostly not among the new Q classes) was pinned by digest too, but its float32
distance ties fall differently on another CPU (a Xeon with AVX-512 and AMX, 2026-12-04: sizes [38, 41, 32, 1]
where the digest's machine gives [38, 43, 32, 1], with the same packages), so a digest of it is not portable.
What the class indices rely on is checked instead, on any CPU: a warm-started ENNC gives the same prototypes for
any labels in the same order.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from algorithm import ENNC
from algorithm.phase1 import Phase1Config, Phase1Result, phase1
from algorithm.transitions import Transitions

N_ACTIONS = 4
"""Action 3 never occurs in the data: phase 1 keeps its previous prototypes."""
COLD_DIGEST = "e15166c102193def53354bd0b8f3e33ac971a9aa1c058893861b2a52d167ff3e"


def transitions(n: int, seed: int) -> Transitions:
    """2-D states; terminal (reward −1) left of x = −0.6; elsewhere y rounded to a step of 0.1 (21 values in
    [−1, 1]), or of 0.5 after action 2 (5 values: its first fit takes the rounded values as they are)."""
    rng = np.random.default_rng(seed)
    state = rng.uniform(-1.0, 1.0, (n, 2))
    action = rng.integers(0, N_ACTIONS - 1, n)
    done = state[:, 0] < -0.6
    step = np.where(action == 2, 0.5, 0.1)
    return Transitions(
        robot=np.zeros(n, np.int16),
        state=state.astype(np.float32),
        action=action.astype(np.uint8),
        reward=np.where(done, -1.0, np.round(state[:, 1] / step) * step).astype(np.float32),
        next_state=np.clip(state + rng.normal(0.0, 0.2, (n, 2)), -1.0, 1.0).astype(np.float32),
        done=done,
    )


def digest(result: Phase1Result) -> str:
    disc = result.discretization
    assert disc.scale is not None
    parts = [disc.prototypes, disc.labels, disc.offsets, disc.scale, np.asarray(result.changed)]
    return hashlib.sha256(b"".join(np.ascontiguousarray(p).tobytes() for p in parts)).hexdigest()


def phase1_runs() -> tuple[Phase1Result, Phase1Result]:
    """A cold run (3 iterations, one ENNC per action on at most 150 of ~200 tuples, 8 classes at most), then a
    warm-started run on other tuples from its discretization."""
    cold = phase1(
        transitions(600, 0),
        N_ACTIONS,
        Phase1Config(n_cycles=25, max_iterations=3, max_classes=8, max_patterns=150),
        seed=11,
    )
    warm = phase1(
        transitions(500, 1),
        N_ACTIONS,
        Phase1Config(n_cycles=20, max_iterations=2, max_classes=8),
        seed=12,
        warm_start=cold.discretization,
    )
    return cold, warm


@pytest.fixture(scope="module")
def results() -> tuple[Phase1Result, Phase1Result]:
    return phase1_runs()


def test_cold_phase1_prototypes_are_those_of_the_code_before_class_indices(
    results: tuple[Phase1Result, Phase1Result],
) -> None:
    cold = results[0]
    assert cold.iterations == 3
    assert cold.discretization.sizes().tolist() == [37, 34, 37, 1]
    # Non-integer Q values, which a classifier refuses as targets: phase 1 must map them to classes and back.
    labels = cold.discretization.labels
    assert not np.all(labels == np.round(labels))
    assert digest(cold) == COLD_DIGEST


def test_warm_started_phase1_keeps_an_unseen_actions_label_and_grows_the_others(
    results: tuple[Phase1Result, Phase1Result],
) -> None:
    cold, warm = results
    assert warm.iterations == 2
    before, after = cold.discretization, warm.discretization
    # Action 3 has no tuples: the warm start keeps its one prototype and its label.
    assert after.sizes()[3] == before.sizes()[3] == 1
    assert after.labels[after.offsets[3] :].tolist() == before.labels[before.offsets[3] :].tolist()
    assert after.sizes()[:3].min() > 8


def test_a_warm_started_ennc_gives_the_same_prototypes_for_any_labels_in_the_same_order() -> None:
    data = transitions(500, 1)
    states = data.state.astype(np.float64)
    classes, index = np.unique(data.reward, return_inverse=True)
    start = np.random.default_rng(5).choice(len(states), 30, replace=False)
    init_index = index[start]

    def fit(labels: np.ndarray, init_labels: np.ndarray) -> ENNC:
        return ENNC(n_cycles=20, random_state=12).fit(
            states, labels, init_prototypes=states[start] + 0.01, init_labels=init_labels
        )

    by_index = fit(index, init_index)
    # Another numbering in the same order (as the Q values themselves were before), absent labels in between.
    by_other = fit(7 * index - 40, 7 * init_index - 40)
    assert by_index.n_prototypes_ > len(start)
    np.testing.assert_array_equal(by_index.prototypes_, by_other.prototypes_)
    np.testing.assert_array_equal(7 * by_index.labels_ - 40, by_other.labels_)
    assert len(classes) > 8


def test_union_cells_give_every_action_every_prototype_labelled_with_its_own_q_there(
    results: tuple[Phase1Result, Phase1Result],
) -> None:
    own = results[0].discretization
    config = Phase1Config(n_cycles=25, max_iterations=3, max_classes=8, max_patterns=150, cells="union")
    union = phase1(transitions(600, 0), N_ACTIONS, config, seed=11).discretization
    # The same fits as the per-action run, then every action's cells made the union of all of them.
    assert union.is_shared()
    assert union.sizes().tolist() == [own.size] * N_ACTIONS
    assert union.scale is not None and own.scale is not None
    np.testing.assert_array_equal(union.scale, own.scale)
    for a in range(N_ACTIONS):
        np.testing.assert_array_equal(union.action_prototypes(a), own.prototypes)
        labels = union.labels[union.offsets[a] : union.offsets[a + 1]]
        # At its own prototypes an action keeps its labels; elsewhere it reads its nearest own prototype's label,
        # nearest in the scaled metric (brute force here).
        mine = own.action_prototypes(a) / own.scale
        distance = (((own.prototypes / own.scale)[:, None, :] - mine[None, :, :]) ** 2).sum(axis=-1)
        expected = own.labels[own.offsets[a] + distance.argmin(axis=1)]
        np.testing.assert_array_equal(labels, expected)
        block = slice(own.offsets[a], own.offsets[a + 1])
        np.testing.assert_array_equal(labels[block], own.labels[block])
    # One search gives each state one cell index per action, offset by the action's block.
    cells = union.cells(transitions(50, 3).state)
    np.testing.assert_array_equal(cells - union.offsets[:-1], np.repeat(cells[:, :1], N_ACTIONS, axis=1))


def test_phase1_refuses_unknown_cells() -> None:
    with pytest.raises(ValueError, match="cells must be"):
        Phase1Config(cells="shared")  # type: ignore[arg-type]
