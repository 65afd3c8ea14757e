"""The learner's bounded experience store and its per-sender sequence ledger.

The store is a ring buffer of columnar tuples: memory is fixed at construction, and when it is full the oldest
tuples are overwritten (counted in ``overwritten``). The ledger de-duplicates batches by (actor, incarnation,
seq) and counts the sequence numbers that never arrived. Both round-trip through plain arrays for checkpoints.

Usage::

    store = ExperienceStore(capacity=2_000_000, dim=6)
    if ledger.accept(actor, incarnation, seq):
        store.add(transitions)
    sample = store.sample(100_000, rng)
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field

import numpy as np

from algorithm.transitions import Transitions

log = logging.getLogger(__name__)


class ExperienceStore:
    """A fixed-capacity ring buffer of tuples ⟨robot, s, a, r, s′, done, policy_version⟩."""

    def __init__(self, capacity: int, dim: int) -> None:
        if capacity < 1 or dim < 1:
            raise ValueError("capacity and dim must be positive")
        self.capacity = capacity
        self.dim = dim
        self.robot = np.zeros(capacity, np.int16)
        self.state = np.zeros((capacity, dim), np.float32)
        self.action = np.zeros(capacity, np.uint8)
        self.reward = np.zeros(capacity, np.float32)
        self.next_state = np.zeros((capacity, dim), np.float32)
        self.done = np.zeros(capacity, bool)
        self.policy_version = np.zeros(capacity, np.int64)
        self.total = 0
        """Tuples ever added."""
        self._head = 0  # next slot to write
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
            batch = batch.take(np.arange(n - self.capacity, n))
            self.total += n - self.capacity
            n = self.capacity
        # At most two contiguous slice writes (the ring wraps once): fancy indexing cost twice as much per batch.
        first = min(n, self.capacity - self._head)
        for lo, hi, src in ((self._head, self._head + first, slice(0, first)), (0, n - first, slice(first, n))):
            if hi <= lo:
                continue
            self.robot[lo:hi] = batch.robot[src]
            self.state[lo:hi] = batch.state[src]
            self.action[lo:hi] = batch.action[src]
            self.reward[lo:hi] = batch.reward[src]
            self.next_state[lo:hi] = batch.next_state[src]
            self.done[lo:hi] = batch.done[src]
            self.policy_version[lo:hi] = policy_version
        self.total += n
        self._head = int((self._head + n) % self.capacity)
        self._size = min(self._size + n, self.capacity)

    def view(self, index: np.ndarray | None = None) -> Transitions:
        """The stored tuples (all, or those at ``index`` < len) as :class:`Transitions` (copies)."""
        stored = Transitions(
            robot=self.robot,
            state=self.state,
            action=self.action,
            reward=self.reward,
            next_state=self.next_state,
            done=self.done,
        )
        return stored.take(np.arange(len(self)) if index is None else index)

    def sample(self, n: int, rng: np.random.Generator) -> Transitions:
        """At most ``n`` stored tuples drawn uniformly without replacement."""
        size = len(self)
        if n >= size:
            return self.view()
        return self.view(np.sort(rng.choice(size, n, replace=False)))

    def to_arrays(self) -> dict[str, np.ndarray]:
        size = len(self)
        order = (self._head - size + np.arange(size)) % self.capacity  # oldest first: a restore keeps the age order
        return {
            "store_robot": self.robot[order],
            "store_state": self.state[order],
            "store_action": self.action[order],
            "store_reward": self.reward[order],
            "store_next_state": self.next_state[order],
            "store_done": self.done[order],
            "store_policy_version": self.policy_version[order],
            "store_meta": np.array([self.capacity, self.dim, self.total], np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], capacity: int | None = None) -> ExperienceStore:
        saved_capacity, dim, total = (int(v) for v in arrays["store_meta"])
        store = cls(capacity or saved_capacity, dim)
        keep = slice(max(0, len(arrays["store_reward"]) - store.capacity), None)  # the newest, if it shrank
        n = len(arrays["store_reward"][keep])
        for name in ("robot", "state", "action", "reward", "next_state", "done", "policy_version"):
            getattr(store, name)[:n] = arrays[f"store_{name}"][keep]
        store._size = n
        store._head = n % store.capacity
        store.total = max(total, n)
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
        """Times a seq arrived past the next expected one (logged: the first 10, then every 1000th)."""

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
            # Not lost yet: a re-send may still fill it (the outbox re-sends what is not acknowledged).
            log.warning(
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
        blob = json.dumps({"streams": state, "duplicates": self.duplicates, "accepted": self.accepted})
        return {"ledger": np.frombuffer(blob.encode(), np.uint8)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> SequenceLedger:
        data = json.loads(arrays["ledger"].tobytes().decode())
        ledger = cls()
        ledger.duplicates = int(data["duplicates"])
        ledger.accepted = int(data["accepted"])
        for sender, incarnation, contiguous, ahead in data["streams"]:
            ledger.streams[(sender, int(incarnation))] = _Stream(int(contiguous), set(ahead))
        return ledger
