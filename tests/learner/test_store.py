"""The bounded experience store and the sequence ledger."""

from __future__ import annotations

import numpy as np
import pytest

from algorithm.transitions import Transitions
from learner.store import RESTORE_CHUNK, ExperienceStore, SequenceLedger


def batch(start: int, n: int, dim: int = 2) -> Transitions:
    values = np.arange(start, start + n)
    return Transitions(
        robot=(values % 7).astype(np.int16),
        state=np.repeat(values[:, None], dim, 1).astype(np.float32),
        action=(values % 8).astype(np.uint8),
        reward=values.astype(np.float32),
        next_state=np.repeat(values[:, None] + 1, dim, 1).astype(np.float32),
        done=values % 5 == 0,
    )


def test_store_keeps_the_newest_tuples_within_capacity() -> None:
    store = ExperienceStore(capacity=10, dim=2)
    store.add(batch(0, 4), policy_version=1)
    store.add(batch(4, 9), policy_version=2)
    assert len(store) == 10 and store.total == 13 and store.overwritten == 3
    assert sorted(store.view().reward.tolist()) == list(range(3, 13))
    store.add(batch(100, 25))  # larger than the store: only its last 10 remain
    assert sorted(store.view().reward.tolist()) == list(range(115, 125))
    assert store.total == 38


def test_store_round_trips_through_arrays_in_age_order() -> None:
    store = ExperienceStore(capacity=10, dim=3)
    store.add(batch(0, 7, 3), policy_version=1)
    store.add(batch(7, 6, 3), policy_version=4)
    restored = ExperienceStore.from_arrays(store.to_arrays())
    assert (restored.total, len(restored), restored.capacity) == (13, 10, 10)
    np.testing.assert_array_equal(np.sort(restored.view().reward), np.sort(store.view().reward))
    assert sorted(restored.policy_version.tolist()) == [1] * 4 + [4] * 6
    # Adding after a restore overwrites the oldest tuples, as before the restore.
    restored.add(batch(50, 2, 3), policy_version=5)
    assert 3.0 not in restored.view().reward and 4.0 not in restored.view().reward


def test_store_keeps_wire_batches_without_a_copy_and_copies_writeable_ones() -> None:
    store = ExperienceStore(capacity=100, dim=2)
    wire = batch(0, 10)
    for column in (wire.robot, wire.state, wire.action, wire.reward, wire.next_state, wire.done):
        column.flags.writeable = False
    own = batch(10, 5)
    store.add(wire)
    store.add(own)
    own.reward[:] = -1.0  # the sender changes its arrays after handing them over
    assert store.view().reward.tolist() == list(range(15))
    assert np.shares_memory(store._batches[0].tuples.state, wire.state)
    with pytest.raises(ValueError, match="dimension"):
        store.add(batch(0, 3, dim=4))


def test_a_restored_store_is_cut_into_chunks_that_keep_their_versions() -> None:
    store = ExperienceStore(capacity=3 * RESTORE_CHUNK, dim=2)
    store.add(batch(0, RESTORE_CHUNK + 5), policy_version=1)
    store.add(batch(RESTORE_CHUNK + 5, RESTORE_CHUNK), policy_version=2)
    restored = ExperienceStore.from_arrays(store.to_arrays())
    assert [len(b.tuples) for b in restored._batches] == [RESTORE_CHUNK, 5, RESTORE_CHUNK - 5, 5]
    np.testing.assert_array_equal(restored.policy_version, store.policy_version)
    np.testing.assert_array_equal(restored.view().reward, np.arange(2 * RESTORE_CHUNK + 5))
    # Overwriting the oldest chunk frees it whole: nothing stored holds its memory any more.
    first = restored._batches[0].tuples.state
    restored.add(batch(0, RESTORE_CHUNK + 2 * RESTORE_CHUNK - 5))
    assert not any(np.shares_memory(b.tuples.state, first) for b in restored._batches)
    assert len(restored) == restored.capacity


def test_ledger_deduplicates_and_counts_gaps() -> None:
    ledger = SequenceLedger()
    assert [ledger.accept("a", 1, s) for s in (0, 1, 1, 3)] == [True, True, False, True]
    assert ledger.duplicates == 1 and ledger.accepted == 3
    assert ledger.acked("a", 1) == 1 and ledger.gaps == 1  # seq 2 missing
    assert ledger.accept("a", 1, 2)
    assert ledger.acked("a", 1) == 3 and ledger.gaps == 0
    # A new incarnation of the same actor is a new stream.
    assert ledger.accept("a", 2, 0) and ledger.acked("a", 2) == 0
    assert ledger.acked("b", 1) == -1
    restored = SequenceLedger.from_arrays(ledger.to_arrays())
    assert not restored.accept("a", 1, 3)
    assert restored.acked("a", 1) == 3 and restored.duplicates == 2


def test_an_arrival_out_of_order_is_counted_not_warned(caplog: pytest.LogCaptureFixture) -> None:
    """Experience and increments share a sequence on two subscriptions: a seq past the next one is usual and fills;
    it is a figure of the report (``gap_events``), while what never fills stays in ``gaps``."""
    ledger = SequenceLedger()
    with caplog.at_level("DEBUG", logger="learner.store"):
        assert ledger.accept("a", 7, 0) and ledger.accept("a", 7, 3)
        assert ledger.accept("a", 7, 1)  # fills part of it: no new gap
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
        ("DEBUG", "gap in the stream of a (incarnation 7): seq 3 arrived after 0; 2 sequence numbers missing")
    ]
    assert ledger.gaps == 1 and ledger.gap_events == 1
    assert SequenceLedger.from_arrays(ledger.to_arrays()).gap_events == 1
