"""The hostile peer: a session of chaos's own publishing raw bytes past the publish-side checks (:class:`Peer`),
the learner's replies to it (:class:`Replies`), a poisoned batch, and whether a session opens at all."""

from __future__ import annotations

import json
import threading
from types import TracebackType
from typing import Any, Self

import msgpack
import numpy as np
import zenoh

from protocol import Ack, ExperienceBatch, KeySpace, Reject, ZenohTransport, encode
from sim.formulation import Formulation
from tools.chaos.observe import RECOVERY_TIMEOUT_S, wait_for

POISON_TUPLES, INTRUDER_TUPLES, SPOOF_PUTS = 5, 3, 3
"""Tuples per batch of a poison round (two of its three batches are stored: mallory's count is 10 per round, so any
other batch stored under its id shows), tuples of the batch a session that should have been refused puts as mallory,
and lying batches per spoof (each way)."""
REFUSAL_TIMEOUT_MS = 3000
"""``connect/timeout_ms`` of a session that should be refused: zenoh.open gives up (ZError) after it."""


class Replies:
    """The learner's Rejects and Acks of one incarnation of a peer's stream."""

    def __init__(self, incarnation: int) -> None:
        self.incarnation = incarnation
        self.rejected: list[int] = []
        self.reasons: list[str] = []
        self.acked = -1
        self._lock = threading.Lock()

    def on_reject(self, msg: Reject) -> None:
        if msg.incarnation == self.incarnation:
            with self._lock:
                self.rejected.append(msg.seq)
                self.reasons.append(msg.reason)

    def on_ack(self, msg: Ack) -> None:
        if msg.incarnation == self.incarnation:
            with self._lock:
                self.acked = max(self.acked, msg.seq)

    def got(self, reject: int, ack: int) -> bool:
        with self._lock:
            return reject in self.rejected and self.acked >= ack


class Peer:
    """A session of chaos's own playing a peer under ``ident``, publishing raw bytes past the publish-side checks."""

    def __init__(self, conf: zenoh.Config, keys: KeySpace, ident: str, formulation: Formulation) -> None:
        self.keys = keys
        self.ident = ident
        self.formulation = formulation
        """The run's: the learner refuses batches of any other, so the peer's must pass that check to test the rest."""
        self.dims = formulation.dim
        self.own_key = keys.experience(ident)
        self.transport = ZenohTransport.open(conf, keys)

    def listen(self, replies: Replies) -> None:
        self.transport.subscribe(self.keys.reject(self.ident), Reject, replies.on_reject)
        self.transport.subscribe(self.keys.ack(self.ident), Ack, replies.on_ack)

    def await_learner(self) -> None:
        """Until the learner's subscription reaches this session: what is put before goes nowhere."""
        wait_for("the learner's subscription", RECOVERY_TIMEOUT_S, lambda: self.transport.has_subscribers(self.own_key))

    def batch(self, seq: int, incarnation: int, n: int = POISON_TUPLES, actor_id: str | None = None) -> ExperienceBatch:
        return ExperienceBatch(
            actor_id=actor_id or self.ident,
            incarnation=incarnation,
            seq=seq,
            policy_version=0,
            featurizer=self.formulation.featurizer.name,
            reward_function=self.formulation.reward.name,
            action_set=self.formulation.actions.name,
            robot=np.zeros(n, np.int16),
            state=np.zeros((n, self.dims), np.float32),
            action=np.zeros(n, np.uint8),
            reward=np.zeros(n, np.float32),
            next_state=np.zeros((n, self.dims), np.float32),
            done=np.zeros(n, bool),
        )

    def put(self, key: str, payload: bytes) -> None:
        # BLOCK as the protocol's data keys: what is not delivered must be the router's or the learner's doing.
        self.transport.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def opens(conf: dict[str, Any]) -> bool:
    """Whether a zenoh session with ``conf`` opens within REFUSAL_TIMEOUT_MS."""
    conf["connect"]["timeout_ms"] = REFUSAL_TIMEOUT_MS
    try:
        with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))):
            return True
    except zenoh.ZError:
        return False


def poisoned(batch: ExperienceBatch) -> bytes:
    """``batch`` on the wire with NaN rewards: its envelope, id and seq readable, its values invalid (docs §5.6)."""
    version, tag, fields = msgpack.unpackb(encode(batch), raw=False)
    fields["reward"][2] = np.full(batch.n_tuples, np.nan, "<f4").tobytes()
    data: bytes = msgpack.packb([version, tag, fields], use_bin_type=True)
    return data
