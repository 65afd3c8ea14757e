"""The learner's experience intake: validate, de-duplicate and store the actors' batches, reject what it refuses for
good, and say what can be acked.

Usage (handlers run on transport worker threads; every method is thread-safe and takes the intake's own lock)::

    intake = ExperienceIntake(capacity=1_000_000, formulation=FORMULATIONS["paper"], transport=transport)
    transport.subscribe(keys.experience(), ExperienceBatch, intake.on_experience, intake.on_rejected)
    intake.accept_sequence(actor, incarnation, seq)     # a Q-table increment shares its sender's sequence
    data = intake.snapshot_for_fit()                    # (stored tuples, tuples received so far)
    arrays, acks = intake.checkpoint_arrays()           # what a checkpoint holds, and the acks it then allows
    figures = intake.figures()                          # counters for status and report

**One count per message.** Every arrival is counted once: stored, a duplicate, or a rejection. A message refused
for good (invalid, of another formulation or of another state dimension) that names its sender's own stream takes
its seq in the ledger and is rejected by it (a ``Reject`` to its sender, once), so a re-sent copy is a duplicate
like any re-send, not a second rejection. A refused payload whose seq cannot be read, or that claims another
sender's stream, is counted at each arrival: nothing ties two copies of it together.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from algorithm.transitions import Transitions
from algorithm.wire import formulation_mismatch, transitions_from_batch
from learner.store import ExperienceStore, SequenceLedger
from protocol import DEFAULT_KEYS, ExperienceBatch, ProtocolError, Reject, Transport, peek_sequence
from protocol.messages import MAX_NAME_LEN
from sim.formulation import Formulation

log = logging.getLogger(__name__)

STATE_DIMENSION = "StateDimension"
"""``rejected_by_type`` name of a valid batch over another state dimension than the learner's featurizer."""
FORMULATION = "Formulation"
"""``rejected_by_type`` name of a valid batch stamped with another formulation than the learner's: its tuples mean
something else (another state, reward or action set)."""

_LOG_FIRST = 10
_LOG_EVERY = 1000


@dataclass(frozen=True, slots=True)
class IntakeFigures:
    tuples_received: int
    store_size: int
    overwritten: int
    accepted: int
    """Batches and increments accepted (each sequence number once)."""
    duplicates: int
    """Messages received again and ignored: re-sends, of a message stored or of one already rejected."""
    gaps: int
    out_of_order: int
    """Arrivals past the next expected sequence number, filled later or not (see ``gaps``)."""
    rejected_by_type: dict[str, int]
    """Messages refused over the run (resumes included), by error class of docs/reference/protocol.md §6, each once."""
    refused: int
    """Of those, the ones rejected explicitly by sequence number (a Reject sent)."""
    tuples_per_s: float
    tuples_by_actor: dict[str, int] = field(default_factory=dict)
    latest_version: dict[str, int] = field(default_factory=dict)
    """Policy version of each actor's newest batch (for the policy-lag figure)."""

    @property
    def rejected(self) -> int:
        return sum(self.rejected_by_type.values())


class ExperienceIntake:
    """Store + ledger + rejection counts behind one lock, with the figures the learner reports."""

    def __init__(self, capacity: int, formulation: Formulation, transport: Transport | None = None) -> None:
        self.formulation = formulation
        """What every stored tuple was made under: a batch stamped with another formulation is refused."""
        self.transport = transport
        """Where Rejects go (None: refusals are only counted, as in the transport benchmark)."""
        self._keys = DEFAULT_KEYS if transport is None else transport.keys
        self._lock = threading.Lock()
        self._store = ExperienceStore(capacity, formulation.dim)
        self._ledger = SequenceLedger()
        self._rejected: Counter[str] = Counter()
        self._refused = 0
        self._received = 0
        self._by_actor: dict[str, int] = {}
        self._latest_version: dict[str, int] = {}
        self._started = time.monotonic()
        self._received_before = 0  # tuples received before a resume: the rate counts this process only

    def on_experience(self, msg: ExperienceBatch) -> None:
        kind, reason = self._mismatch(msg)
        if reason:
            self._refuse((msg.actor_id, msg.incarnation, msg.seq), kind, reason)
            return
        batch = transitions_from_batch(msg)
        with self._lock:
            if not self._ledger.accept(msg.actor_id, msg.incarnation, msg.seq):
                return
            self._store.add(batch, msg.policy_version)
            self._received += len(batch)
            self._by_actor[msg.actor_id] = self._by_actor.get(msg.actor_id, 0) + len(batch)
            self._latest_version[msg.actor_id] = max(self._latest_version.get(msg.actor_id, 0), msg.policy_version)

    def _mismatch(self, msg: ExperienceBatch) -> tuple[str, str]:
        """(kind, why) ``msg`` cannot join the store, or ("", ""): tuples of another formulation mean something else.
        The reason names the first part that differs (a Reject's reason holds 64 characters)."""
        mismatch = formulation_mismatch(self.formulation, msg)
        if mismatch:
            return FORMULATION, mismatch
        if msg.state.shape[1] != self._store.dim:
            return STATE_DIMENSION, f"state dimension {msg.state.shape[1]}, expected {self._store.dim}"
        return "", ""

    def on_rejected(self, key: str, payload: bytes, error: ProtocolError) -> None:
        """A payload the transport refused on an actor's key (the transport's ``on_reject``): rejected by its seq
        if it names its sender's own stream. Never by seq for a payload that claims another sender's stream (a
        lie must not make the genuine sender drop its message)."""
        peeked = peek_sequence(payload)
        own = peeked is not None and peeked[0] == self._keys.owner(key)
        self._refuse(peeked if own else None, type(error).__name__, f"{type(error).__name__}: {error}")

    def _refuse(self, sequence: tuple[str, int, int] | None, kind: str, reason: str) -> None:
        with self._lock:
            if sequence is not None and not self._ledger.accept(*sequence):
                return  # a copy of a message already settled: counted as a duplicate by the ledger
            self._rejected[kind] += 1
            n = self._rejected[kind]
            if sequence is not None:
                self._refused += 1
        if sequence is None:
            return  # the transport logged it
        actor, incarnation, seq = sequence
        if n <= _LOG_FIRST or n % _LOG_EVERY == 0:
            log.warning("rejected seq %d of %s (incarnation %x, %s #%d): %s", seq, actor, incarnation, kind, n, reason)
        if self.transport is not None:  # published outside the lock: a blocked publish must not hold up checkpoints
            printable = "".join(c if c.isprintable() else "?" for c in reason)[:MAX_NAME_LEN]
            msg = Reject(actor_id=actor, incarnation=incarnation, seq=seq, reason=printable)
            self.transport.publish(self._keys.reject(actor), msg)

    def accept_sequence(self, sender: str, incarnation: int, seq: int) -> bool:
        """Ledger entry for a non-experience message that shares the sender's sequence (Q-table increments)."""
        with self._lock:
            return self._ledger.accept(sender, incarnation, seq)

    def __len__(self) -> int:
        with self._lock:
            return len(self._store)

    @property
    def tuples_received(self) -> int:
        with self._lock:
            return self._received

    def snapshot_for_fit(self) -> tuple[Transitions, int]:
        """A copy of the stored tuples and the count of tuples received when it was taken."""
        with self._lock:
            return self._store.view(), self._received

    def checkpoint_arrays(self) -> tuple[dict[str, np.ndarray], list[tuple[str, int, int]]]:
        """The store, ledger and counts as arrays, and (actor, incarnation, seq) of every stream's cumulative ack:
        every seq up to it is in these arrays, so once they are on disk those acks may be sent."""
        with self._lock:
            meta = {
                "received": self._received,
                "by_actor": self._by_actor,
                "rejected_by_type": dict(self._rejected),
                "refused": self._refused,
            }
            arrays = {
                **self._store.to_arrays(),
                **self._ledger.to_arrays(),
                "intake_meta": np.frombuffer(json.dumps(meta).encode(), np.uint8),
            }
            acks = [
                (sender, incarnation, stream.contiguous)
                for (sender, incarnation), stream in self._ledger.streams.items()
                if stream.contiguous >= 0
            ]
        return arrays, acks

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Continue from a checkpoint's arrays (the store keeps this intake's capacity)."""
        meta = json.loads(arrays["intake_meta"].tobytes().decode())
        with self._lock:
            self._store = ExperienceStore.from_arrays(arrays, self._store.capacity)
            self._ledger = SequenceLedger.from_arrays(arrays)
            self._received = self._received_before = int(meta["received"])
            self._by_actor = {k: int(v) for k, v in meta["by_actor"].items()}
            self._rejected = Counter({str(k): int(v) for k, v in meta["rejected_by_type"].items()})
            self._refused = int(meta["refused"])

    def figures(self) -> IntakeFigures:
        with self._lock:
            return IntakeFigures(
                tuples_received=self._received,
                store_size=len(self._store),
                overwritten=self._store.overwritten,
                accepted=self._ledger.accepted,
                duplicates=self._ledger.duplicates,
                gaps=self._ledger.gaps,
                out_of_order=self._ledger.gap_events,
                rejected_by_type=dict(self._rejected),
                refused=self._refused,
                tuples_per_s=(self._received - self._received_before) / max(time.monotonic() - self._started, 1e-9),
                tuples_by_actor=dict(self._by_actor),
                latest_version=dict(self._latest_version),
            )
