"""The learner's receive path for experience: validate, de-duplicate, store, and track what can be acked.

Usage (handlers run on transport worker threads; every method is thread-safe)::

    ingest = Ingest(ExperienceStore(capacity, dim))
    transport.subscribe(keys.experience(), ExperienceBatch, ingest.on_experience)
    ...
    for actor_id, incarnation, seq in ingest.ack_points():   # after a checkpoint: every seq <= this is stored
        transport.publish(keys.ack(actor_id), Ack(actor_id=actor_id, incarnation=incarnation, seq=seq))
"""

from __future__ import annotations

import logging
import threading
import time
from collections import defaultdict

import numpy as np

from algorithm.transitions import Transitions
from learner.store import ExperienceStore, SequenceLedger
from protocol import ExperienceBatch

log = logging.getLogger(__name__)


class Ingest:
    """Thread-safe store + ledger with the figures the learner reports."""

    def __init__(self, store: ExperienceStore, ledger: SequenceLedger | None = None) -> None:
        self.store = store
        self.ledger = ledger or SequenceLedger()
        self.lock = threading.Lock()
        self.rejected = 0
        """Batches refused here (wrong state dimension); transport-level rejections are counted there."""
        self.tuples_received = 0
        self.latest_version: dict[str, int] = {}
        """Policy version of each actor's newest batch (for the policy-lag figure)."""
        self.tuples_by_actor: defaultdict[str, int] = defaultdict(int)
        self.started = time.monotonic()

    def on_experience(self, msg: ExperienceBatch) -> None:
        if msg.state.shape[1] != self.store.dim:
            with self.lock:
                self.rejected += 1
                count = self.rejected
            if count <= 10 or count % 1000 == 0:
                log.warning(
                    "rejected experience from %s: state dimension %d, expected %d (%d rejected so far)",
                    msg.actor_id,
                    msg.state.shape[1],
                    self.store.dim,
                    count,
                )
            return
        batch = Transitions(
            robot=np.asarray(msg.robot),
            state=np.asarray(msg.state),
            action=np.asarray(msg.action),
            reward=np.asarray(msg.reward),
            next_state=np.asarray(msg.next_state),
            done=np.asarray(msg.done),
        )
        with self.lock:
            if not self.ledger.accept(msg.actor_id, msg.incarnation, msg.seq):
                return
            self.store.add(batch, msg.policy_version)
            self.tuples_received += len(batch)
            self.tuples_by_actor[msg.actor_id] += len(batch)
            self.latest_version[msg.actor_id] = max(self.latest_version.get(msg.actor_id, 0), msg.policy_version)

    def accept_sequence(self, sender: str, incarnation: int, seq: int) -> bool:
        """Ledger entry for a non-experience message that shares the sender's sequence (Q-table increments)."""
        with self.lock:
            return self.ledger.accept(sender, incarnation, seq)

    def ack_points(self) -> list[tuple[str, int, int]]:
        """(actor, incarnation, seq): every stream's cumulative acknowledgement."""
        with self.lock:
            return [
                (sender, incarnation, stream.contiguous)
                for (sender, incarnation), stream in self.ledger.streams.items()
                if stream.contiguous >= 0
            ]

    def tuples_per_s(self) -> float:
        return self.tuples_received / max(time.monotonic() - self.started, 1e-9)
