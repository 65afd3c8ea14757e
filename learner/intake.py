"""The learner's experience intake: validate, de-duplicate and store the actors' batches, and say what can be acked.

Usage (handlers run on transport worker threads; every method is thread-safe and takes the intake's own lock)::

    intake = ExperienceIntake(capacity=1_000_000, formulation=FORMULATIONS["paper"])
    transport.subscribe(keys.experience(), ExperienceBatch, intake.on_experience)
    intake.accept_sequence(actor, incarnation, seq)     # a Q-table increment shares its sender's sequence
    data = intake.snapshot_for_fit()                    # (stored tuples, tuples received so far)
    arrays, acks = intake.checkpoint_arrays()           # what a checkpoint holds, and the acks it then allows
    figures = intake.figures()                          # counters for status and report
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from algorithm.transitions import Transitions
from algorithm.wire import transitions_from_batch
from learner.store import ExperienceStore, SequenceLedger
from protocol import ExperienceBatch
from sim.features import FEATURIZERS, Formulation

log = logging.getLogger(__name__)

Refused = Callable[[str, int, int, str], None]


@dataclass(frozen=True, slots=True)
class IntakeFigures:
    tuples_received: int
    store_size: int
    overwritten: int
    accepted: int
    """Batches and increments accepted (each sequence number once)."""
    duplicates: int
    gaps: int
    rejected: int
    """Batches refused here (another formulation, a wrong state dimension); transport-level rejections are counted by
    the transport."""
    refused: int
    """Messages rejected explicitly by sequence number (a Reject sent), here or at the transport."""
    tuples_per_s: float
    tuples_by_actor: dict[str, int] = field(default_factory=dict)
    latest_version: dict[str, int] = field(default_factory=dict)
    """Policy version of each actor's newest batch (for the policy-lag figure)."""


class ExperienceIntake:
    """Store + ledger behind one lock, with the figures the learner reports."""

    def __init__(self, capacity: int, formulation: Formulation, on_refused: Refused | None = None) -> None:
        self.formulation = formulation
        """What every stored tuple was made under: a batch stamped with another formulation is refused."""
        self.on_refused = on_refused
        """Told (actor, incarnation, seq, reason) of a batch refused here, once (the learner sends the Reject)."""
        self._lock = threading.Lock()
        self._store = ExperienceStore(capacity, FEATURIZERS[formulation.featurizer])
        self._ledger = SequenceLedger()
        self._rejected = 0
        self._refused = 0
        self._received = 0
        self._by_actor: dict[str, int] = {}
        self._latest_version: dict[str, int] = {}
        self._started = time.monotonic()
        self._received_before = 0  # tuples received before a resume: the rate counts this process only

    def on_experience(self, msg: ExperienceBatch) -> None:
        reason = self._mismatch(msg)
        if reason:
            with self._lock:
                self._rejected += 1
                count = self._rejected
            if count <= 10 or count % 1000 == 0:
                log.warning("rejected experience from %s: %s (%d rejected so far)", msg.actor_id, reason, count)
            if self.refuse(msg.actor_id, msg.incarnation, msg.seq) and self.on_refused is not None:
                self.on_refused(msg.actor_id, msg.incarnation, msg.seq, reason)
            return
        batch = transitions_from_batch(msg)
        with self._lock:
            if not self._ledger.accept(msg.actor_id, msg.incarnation, msg.seq):
                return
            self._store.add(batch, msg.policy_version)
            self._received += len(batch)
            self._by_actor[msg.actor_id] = self._by_actor.get(msg.actor_id, 0) + len(batch)
            self._latest_version[msg.actor_id] = max(self._latest_version.get(msg.actor_id, 0), msg.policy_version)

    def _mismatch(self, msg: ExperienceBatch) -> str:
        """Why ``msg`` cannot join the store ("" if it can): tuples of another formulation mean something else. The
        reason names the first part that differs (a Reject's reason holds 64 characters)."""
        own = self.formulation
        for part, theirs, mine in (
            ("featurizer", msg.featurizer, own.featurizer),
            ("reward_function", msg.reward_function, own.reward),
            ("action_set", msg.action_set, own.actions),
        ):
            if theirs != mine:
                return f"{part} {theirs}, expected {mine}"
        if msg.state.shape[1] != self._store.dim:
            return f"state dimension {msg.state.shape[1]}, expected {self._store.dim}"
        return ""

    def refuse(self, sender: str, incarnation: int, seq: int) -> bool:
        """A message refused for good: its seq counts as arrived (the cumulative ack steps over it). True the first
        time, when the sender must be told (a Reject) so that it drops the message instead of re-sending it."""
        with self._lock:
            first = self._ledger.accept(sender, incarnation, seq)
            if first:
                self._refused += 1
        return first

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
        """The store and ledger as arrays, and (actor, incarnation, seq) of every stream's cumulative ack: every seq
        up to it is in these arrays, so once they are on disk those acks may be sent."""
        with self._lock:
            arrays = {
                **self._store.to_arrays(),
                **self._ledger.to_arrays(),
                "intake_meta": np.frombuffer(
                    json.dumps({"received": self._received, "by_actor": self._by_actor}).encode(), np.uint8
                ),
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

    def figures(self) -> IntakeFigures:
        with self._lock:
            return IntakeFigures(
                tuples_received=self._received,
                store_size=len(self._store),
                overwritten=self._store.overwritten,
                accepted=self._ledger.accepted,
                duplicates=self._ledger.duplicates,
                gaps=self._ledger.gaps,
                rejected=self._rejected,
                refused=self._refused,
                tuples_per_s=(self._received - self._received_before) / max(time.monotonic() - self._started, 1e-9),
                tuples_by_actor=dict(self._by_actor),
                latest_version=dict(self._latest_version),
            )
