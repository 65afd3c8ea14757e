"""The actor's outbox (Acme's ``Adder``): the stream's sequence numbers, unacknowledged messages, cumulative acks,
re-sends, back-pressure and the final flush.

Usage (``add``/``flush`` from the actor's loop; ``on_ack``/``on_reject``/``on_learner_join`` from transport
threads)::

    outbox = Outbox(transport, "actor-0", incarnation, limit=256, resend_after=10.0,
                    probe_key=keys.experience("actor-0"), stopping=stop.is_set)
    batch = outbox.add(key, build, policy_version=3)  # waits for room, re-sending what is due; builds
                                                      # build(Header("actor-0", incarnation, <next seq>, 3)),
                                                      # publishes it and keeps it until acknowledged
    outbox.on_ack(ack)                                # every seq <= ack.seq leaves the outbox
    outbox.on_reject(reject)                          # refused for good by the learner: dropped, counted, logged
    outbox.on_learner_join(key)                       # a (re)started learner: everything is sent again
    outbox.flush(timeout=10.0)                        # on stopping: re-send and wait for the last acks
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from protocol import Ack, Header, Message, ProtocolError, Reject, Transport

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)


@dataclass(slots=True)
class _Pending:
    key: str
    msg: Message
    sent_at: float


class Outbox:
    def __init__(
        self,
        transport: Transport,
        actor_id: str,
        incarnation: int,
        limit: int,
        resend_after: float,
        probe_key: str,
        stopping: Callable[[], bool],
        on_acked: Callable[[Message], None] | None = None,
    ) -> None:
        self.transport = transport
        self.actor_id = actor_id
        self.incarnation = incarnation
        self.limit = limit
        self.resend_after = resend_after
        self.probe_key = probe_key
        """A key of ours the learner subscribes to: a re-send after a learner (re)joined waits until it is matched."""
        self.stopping = stopping
        """True once the actor stops (or its duration is over): ``add`` then stops waiting for room."""
        self.on_acked = on_acked
        """Called with each message as its acknowledgement arrives (on the transport's thread)."""
        self._cond = threading.Condition()
        self._pending: OrderedDict[int, _Pending] = OrderedDict()
        self._seq = 0
        """The seq of the next message: every seq below it was sent, so the learner sees no gap."""
        self._acked = -1
        self._resend_all = False
        self.resent = 0
        self.waits = 0
        self.rejected = 0
        """Messages the learner rejected (and this outbox dropped)."""
        self.invalid = 0
        """Messages that failed their own validation while being built, dropped before the wire."""

    def add(self, key: str, build: Callable[[Header], M], *, policy_version: int) -> M | None:
        """Send ``build(header)`` on ``key`` under the stream's next seq and keep it until it is acknowledged or
        rejected; the message sent, or None when nothing was sent and no seq used.

        While ``limit`` messages are unacknowledged it waits for acks, re-sending what is due (back-pressure instead
        of dropping), until ``stopping()``: then nothing is sent. A message that fails its own validation (our bug:
        NaN in a tuple) is counted, logged and dropped here, before the wire, and its seq goes to the next message.
        """
        if not self._wait_for_room():
            return None
        try:
            msg = build(Header(self.actor_id, self.incarnation, self._seq, policy_version))
        except ProtocolError as exc:
            self.invalid += 1
            if self.invalid <= 10 or self.invalid % 1000 == 0:
                log.error("actor %s dropped an invalid message (#%d): %s", self.actor_id, self.invalid, exc)
            return None
        with self._cond:
            self._pending[self._seq] = _Pending(key, msg, time.monotonic())
            self._seq += 1
        self.transport.publish(key, msg)
        return msg

    def on_ack(self, ack: Ack) -> None:
        if ack.incarnation != self.incarnation:
            return  # meant for an earlier incarnation of this actor id
        with self._cond:
            self._acked = max(self._acked, ack.seq)
            while self._pending and next(iter(self._pending)) <= ack.seq:
                _, pending = self._pending.popitem(last=False)
                if self.on_acked is not None:
                    self.on_acked(pending.msg)
            self._cond.notify_all()

    def on_reject(self, reject: Reject) -> None:
        """The learner refused ``reject.seq`` for good: drop it (re-sending would be refused again) and go on."""
        if reject.incarnation != self.incarnation:
            return
        with self._cond:
            dropped = self._pending.pop(reject.seq, None) is not None
            if dropped:
                self.rejected += 1
            n = self.rejected
            self._cond.notify_all()
        if dropped and (n <= 10 or n % 1000 == 0):
            log.error("the learner rejected seq %d (#%d): %s; dropped from the outbox", reject.seq, n, reject.reason)

    def on_learner_join(self, key: str) -> None:
        # A (re)started learner has not seen what it did not acknowledge: send the whole outbox again.
        with self._cond:
            if self._pending:
                self._resend_all = True
                log.info("learner %s joined: re-sending %d unacknowledged messages", key, len(self._pending))

    def _wait_for_room(self) -> bool:
        """Re-send what is due and wait while the outbox is full; False if ``stopping()`` ended the wait first."""
        while True:
            self._resend_due()
            with self._cond:
                if len(self._pending) < self.limit:
                    return True
                if self.stopping():
                    return False
                self.waits += 1
                self._cond.wait(timeout=1.0)

    def flush(self, timeout: float, cut: threading.Event | None = None) -> int:
        """Re-send and wait up to ``timeout`` seconds for the outbox to drain, or until ``cut`` is set; the messages
        still unacknowledged."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not (cut is not None and cut.is_set()):
            self._resend_due()
            with self._cond:
                if not self._pending:
                    break
                self._cond.wait(timeout=0.2)
        return len(self)

    def __len__(self) -> int:
        with self._cond:
            return len(self._pending)

    @property
    def acked(self) -> int:
        """The cumulative acknowledgement: every seq up to it is stored by the learner (-1: none yet)."""
        with self._cond:
            return self._acked

    def _resend_due(self) -> None:
        """Re-send what is overdue, and everything after a learner (re)joined once its subscription is visible here:
        a message published before the new learner's subscriber reaches this session would be lost again. Overdue
        messages go out whether or not it is visible: were this session's view of the learner's subscription to
        stay stale, waiting on it would stop every re-send while a full outbox stops everything else."""
        now = time.monotonic()
        with self._cond:
            everything = self._resend_all and self.transport.has_subscribers(self.probe_key)
            due = [(seq, p) for seq, p in self._pending.items() if everything or now - p.sent_at >= self.resend_after]
            if everything:
                self._resend_all = False
        for seq, pending in due:
            pending.sent_at = now
            self.transport.publish(pending.key, pending.msg)
            self.resent += 1
            log.debug("re-sent seq %d", seq)
