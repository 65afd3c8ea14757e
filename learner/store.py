"""The learner's bounded experience store and its per-sender sequence ledger.

The store keeps the newest ``capacity`` tuples as a queue of the batches they arrived in; when it is full the oldest
tuples go first (counted in ``overwritten``). A batch decoded from the wire is kept as it arrived, without a copy:
its arrays are read-only views on the payload's immutable bytes, so holding them costs exactly their size, and the
receive path copies each tuple once (out of Zenoh) instead of a further time into a ring buffer. Memory is the
stored tuples plus at most one batch, or one restore chunk, that is partly overwritten. The ledger de-duplicates
batches by (actor, incarnation, seq) and counts the sequence numbers that never arrived. Both round-trip through
plain arrays for checkpoints.

Usage::

    store = ExperienceStore(capacity=2_000_000, dim=6)
    if ledger.accept(actor, incarnation, seq):
        store.add(transitions, policy_version)
    everything = store.view()       # one contiguous copy, oldest first
"""

from __future__ import annotations

import json
import logging
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from algorithm.transitions import Transitions

log = logging.getLogger(__name__)

RESTORE_CHUNK = 65536
"""Tuples per batch a restored store is cut into, so that overwriting it frees memory as it goes."""


_COLUMNS = ("robot", "state", "action", "reward", "next_state", "done")


def _copied(batch: Transitions) -> Transitions:
    return Transitions(*(np.array(getattr(batch, name)) for name in _COLUMNS))


def _kept(batch: Transitions) -> Transitions:
    # Read-only arrays are the wire's (views on immutable bytes) and are kept as they are; a writeable one could
    # still be changed by its owner, so the store keeps a copy of it.
    if any(getattr(batch, name).flags.writeable for name in _COLUMNS):
        return _copied(batch)
    return batch


@dataclass(frozen=True, slots=True)
class _Batch:
    tuples: Transitions
    policy_version: int


class ExperienceStore:
    """The newest ``capacity`` tuples ⟨robot, s, a, r, s′, done⟩, each with the policy version that collected it."""

    def __init__(self, capacity: int, dim: int) -> None:
        if capacity < 1 or dim < 1:
            raise ValueError("capacity and dim must be positive")
        self.capacity = capacity
        self.dim = dim
        self.total = 0
        """Tuples ever added."""
        self._batches: deque[_Batch] = deque()
        self._size = 0

    def __len__(self) -> int:
        return self._size

    @property
    def overwritten(self) -> int:
        """Tuples dropped because the store was full (the oldest go first)."""
        return max(0, self.total - self.capacity)

    def add(self, batch: Transitions, policy_version: int = 0) -> None:
        n = len(batch)
        if n == 0:
            return
        if batch.dim != self.dim:
            raise ValueError(f"batch has state dimension {batch.dim}, the store holds {self.dim}")
        if n > self.capacity:
            # Copied, so that the rest of an oversized batch is not held by the slice that stays.
            batch = _copied(batch.take(slice(n - self.capacity, n)))
            self.total += n - self.capacity
            n = self.capacity
        else:
            batch = _kept(batch)
        self._batches.append(_Batch(batch, policy_version))
        self._size += n
        self.total += n
        excess = self._size - self.capacity
        while excess > 0:
            oldest = self._batches[0]
            size = len(oldest.tuples)
            if size <= excess:
                self._batches.popleft()
                self._size -= size
                excess -= size
            else:
                self._batches[0] = _Batch(oldest.tuples.take(slice(excess, size)), oldest.policy_version)
                self._size -= excess
                excess = 0

    def view(self) -> Transitions:
        """Every stored tuple, oldest first, as one :class:`Transitions` (a copy)."""
        if not self._batches:
            return Transitions.empty(self.dim)
        return Transitions.concat([b.tuples for b in self._batches])

    @property
    def policy_version(self) -> np.ndarray:
        """(len,) int64 policy version of every stored tuple, oldest first."""
        return np.concatenate(
            [np.full(len(b.tuples), b.policy_version, np.int64) for b in self._batches] or [np.zeros(0, np.int64)]
        )

    def to_arrays(self) -> dict[str, np.ndarray]:
        stored = self.view()  # oldest first: a restore keeps the age order
        return {
            "store_robot": stored.robot,
            "store_state": stored.state,
            "store_action": stored.action,
            "store_reward": stored.reward,
            "store_next_state": stored.next_state,
            "store_done": stored.done,
            "store_policy_version": self.policy_version,
            "store_meta": np.array([self.capacity, self.dim, self.total], np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], capacity: int | None = None) -> ExperienceStore:
        saved_capacity, dim, total = (int(v) for v in arrays["store_meta"])
        store = cls(capacity or saved_capacity, dim)
        size = len(arrays["store_reward"])
        versions = arrays["store_policy_version"]
        for lo in range(max(0, size - store.capacity), size, RESTORE_CHUNK):  # the newest, if it shrank
            part = slice(lo, min(lo + RESTORE_CHUNK, size))
            # A copy per chunk: the loaded arrays are freed, and a chunk's memory once it is overwritten.
            chunk = Transitions(*(np.array(arrays[f"store_{name}"][part]) for name in _COLUMNS))
            # A chunk holds tuples of one version: cut it where the version changes.
            bounds = np.flatnonzero(np.diff(versions[part])) + 1
            for a, b in zip(np.r_[0, bounds], np.r_[bounds, len(chunk)], strict=True):
                store._batches.append(_Batch(chunk.take(slice(int(a), int(b))), int(versions[part][a])))
        store._size = sum(len(b.tuples) for b in store._batches)
        store.total = max(total, store._size)
        return store


@dataclass
class _Stream:
    contiguous: int = -1
    """Highest seq such that every seq ≤ it has arrived."""
    ahead: set[int] = field(default_factory=set)
    """Arrived seqs above ``contiguous``."""


class SequenceLedger:
    """Exactly-once bookkeeping of batches by (sender, incarnation, seq); seqs start at 0 per incarnation."""

    def __init__(self) -> None:
        self.streams: dict[tuple[str, int], _Stream] = {}
        self.duplicates = 0
        self.accepted = 0
        self.gap_events = 0
        """Times a seq arrived past the next expected one. Experience and Q-table increments share their sender's
        sequence but travel on two subscriptions, so this happens in every healthy run and fills within moments: a
        figure of the report, not a warning. What never fills is :attr:`gaps`."""

    def accept(self, sender: str, incarnation: int, seq: int) -> bool:
        """True the first time a batch is seen; False (and counted) for a duplicate."""
        stream = self.streams.setdefault((sender, incarnation), _Stream())
        if seq <= stream.contiguous or seq in stream.ahead:
            self.duplicates += 1
            return False
        highest = max(stream.ahead, default=stream.contiguous)
        if seq > highest + 1:
            self.gap_events += 1
        if seq > highest + 1 and (self.gap_events <= 10 or self.gap_events % 1000 == 0):
            # Not lost yet: the other subscription's message, or a re-send from the outbox, fills it.
            log.debug(
                "gap in the stream of %s (incarnation %x): seq %d arrived after %d; %d sequence numbers missing",
                sender,
                incarnation,
                seq,
                highest,
                seq - highest - 1,
            )
        stream.ahead.add(seq)
        while stream.contiguous + 1 in stream.ahead:
            stream.contiguous += 1
            stream.ahead.discard(stream.contiguous)
        self.accepted += 1
        return True

    def acked(self, sender: str, incarnation: int) -> int:
        """The cumulative acknowledgement for a stream: every seq ≤ this one is stored (−1: none yet)."""
        stream = self.streams.get((sender, incarnation))
        return -1 if stream is None else stream.contiguous

    @property
    def gaps(self) -> int:
        """Sequence numbers skipped so far: below the highest seen but never received."""
        missing = 0
        for stream in self.streams.values():
            if stream.ahead:
                missing += max(stream.ahead) - stream.contiguous - len(stream.ahead)
        return missing

    def to_arrays(self) -> dict[str, np.ndarray]:
        state = [[s, inc, st.contiguous, sorted(st.ahead)] for (s, inc), st in self.streams.items()]
        counts = {"duplicates": self.duplicates, "accepted": self.accepted, "gap_events": self.gap_events}
        blob = json.dumps({"streams": state, **counts})
        return {"ledger": np.frombuffer(blob.encode(), np.uint8)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> SequenceLedger:
        data = json.loads(arrays["ledger"].tobytes().decode())
        ledger = cls()
        ledger.duplicates = int(data["duplicates"])
        ledger.accepted = int(data["accepted"])
        ledger.gap_events = int(data.get("gap_events", 0))  # checkpoints written before it was kept have none
        for sender, incarnation, contiguous, ahead in data["streams"]:
            ledger.streams[(sender, int(incarnation))] = _Stream(int(contiguous), set(ahead))
        return ledger
