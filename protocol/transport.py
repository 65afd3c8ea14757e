"""The transport interface shared by the in-memory (serial) and zenoh implementations.

A transport moves typed messages on protocol keys; every payload goes through ``protocol.codec`` in both
implementations. Call sequence of a learner and an actor::

    with ZenohTransport.open(conf) as t:          # or InMemoryTransport(bus)
        t.liveliness_token(t.keys.alive("learner", "learner-0"))
        t.liveliness_subscribe(t.keys.alive("actor"), on_join=..., on_leave=...)
        t.subscribe(t.keys.experience(), ExperienceBatch, intake.on_experience)
        t.declare_queryable(t.keys.policy_latest(), lambda: current_policy)
        t.publish(t.keys.policy(), policy)         # broadcast a new version

    with ZenohTransport.open(conf) as t:
        t.subscribe(t.keys.policy(), PolicyUpdate, on_policy)
        replies = t.get(t.keys.policy_latest(), PolicyUpdate)   # late joiner: the current policy
        t.publish(t.keys.experience("actor-0"), batch)           # blocks while the learner lags

Handlers run on a worker thread per subscription (zenoh: calls of one subscription are sequential, in
arrival order; different subscriptions run concurrently) or inside ``publish`` (in-memory). A payload
that fails to decode or validate, or arrives on a key of another message type, is a counted and logged
rejection (``transport.stats``), never an exception in the receiving thread; so are handler exceptions.
Subscribe to the keys of your message type: a ``**`` subscription counts the other types as rejections.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable
from types import TracebackType
from typing import Protocol, Self, TypeVar

from protocol.codec import decode
from protocol.keys import KeySpace
from protocol.messages import Message, ProtocolError, UnexpectedMessageType

log = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

_LOG_FIRST = 10
_LOG_EVERY = 1000


class TransportClosed(RuntimeError):
    """The transport was used after ``close()``."""


class Closeable(Protocol):
    """Handle of a subscription, queryable or liveliness token; ``close()`` undeclares it."""

    def close(self) -> None: ...


class TransportStats:
    """Thread-safe counters of one transport.

    ``rejected`` counts received payloads refused, by ProtocolError class name (e.g. ``MalformedMessage``).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.published = 0
        self.delivered = 0
        self.handler_errors = 0
        self.rejected: Counter[str] = Counter()

    def count_published(self) -> None:
        with self._lock:
            self.published += 1

    def count_delivered(self) -> None:
        with self._lock:
            self.delivered += 1

    def count_handler_error(self) -> int:
        with self._lock:
            self.handler_errors += 1
            return self.handler_errors

    def count_rejected(self, error: ProtocolError) -> int:
        """Count one rejection; return how many of this error type there have been."""
        with self._lock:
            self.rejected[type(error).__name__] += 1
            return self.rejected[type(error).__name__]

    @property
    def rejected_total(self) -> int:
        with self._lock:
            return sum(self.rejected.values())


def _should_log(n: int) -> bool:
    # A hostile or broken peer can send garbage at line rate; log the first few and then a sample.
    return n <= _LOG_FIRST or n % _LOG_EVERY == 0


Rejected = Callable[[str, bytes, ProtocolError], object]
"""``on_reject(key, payload, error)``: told of every payload a subscription refused (e.g. to reject it explicitly)."""


def accept(
    keys: KeySpace,
    stats: TransportStats,
    key: str,
    payload: bytes | memoryview,
    msg_type: type[M],
    on_reject: Rejected | None = None,
) -> M | None:
    """Decode ``payload`` received on ``key``; return it if it is a valid ``msg_type`` allowed on ``key`` and names
    the key's own sender, else count and log the rejection, tell ``on_reject``, and return None."""
    try:
        msg = decode(payload)
        if not isinstance(msg, msg_type):
            raise UnexpectedMessageType(f"{msg.TAG} message on {key!r}, expected {msg_type.TAG}")
        keys.check_message(key, msg)  # its type and sender are the key's
    except ProtocolError as exc:
        n = stats.count_rejected(exc)
        if _should_log(n):
            log.warning("rejected payload on %s (%s #%d): %s", key, type(exc).__name__, n, exc)
        if on_reject is not None:
            run_handler(stats, f"on_reject for {key}", on_reject, key, bytes(payload), exc)
        return None
    return msg


def run_handler(stats: TransportStats, what: str, fn: Callable[..., object], *args: object) -> None:
    """Call ``fn(*args)`` (a user handler); an exception is counted and logged, never propagated."""
    try:
        fn(*args)
    except Exception:
        n = stats.count_handler_error()
        if _should_log(n):
            log.exception("%s raised (handler error #%d)", what, n)


def deliver(
    keys: KeySpace,
    stats: TransportStats,
    key: str,
    payload: bytes | memoryview,
    msg_type: type[M],
    handler: Callable[[M], object],
    on_reject: Rejected | None = None,
) -> None:
    """:func:`accept` the payload and pass it to ``handler``, counting what happens."""
    msg = accept(keys, stats, key, payload, msg_type, on_reject)
    if msg is not None:
        stats.count_delivered()
        run_handler(stats, f"handler for {key}", handler, msg)


class Transport(Protocol):
    """What learner, actors and evaluator need from the network; see the module docstring for usage."""

    keys: KeySpace
    stats: TransportStats

    def publish(self, key: str, msg: Message) -> None:
        """Encode ``msg`` and send it on ``key`` with the key's QoS; may block under back-pressure (BLOCK).

        Raises ProtocolError if ``msg`` is invalid or not the type of ``key``, TransportClosed after close.
        """
        ...

    def subscribe(
        self, key_expr: str, msg_type: type[M], handler: Callable[[M], object], on_reject: Rejected | None = None
    ) -> Closeable:
        """Call ``handler(msg)`` for every valid ``msg_type`` published on keys matching ``key_expr``, and
        ``on_reject(key, payload, error)`` for every payload refused there."""
        ...

    def has_subscribers(self, key: str) -> bool:
        """Whether a subscriber matching ``key`` is known (e.g. wait for the learner before streaming)."""
        ...

    def declare_queryable(self, key: str, fn: Callable[[], Message | None]) -> Closeable:
        """Answer ``get``s on ``key`` with ``fn()`` (no reply when it returns None)."""
        ...

    def get(self, key_expr: str, msg_type: type[M], timeout: float = 2.0) -> list[M]:
        """Query the queryables matching ``key_expr``; the valid replies, possibly none."""
        ...

    def liveliness_token(self, key: str) -> Closeable:
        """Declare this process alive on ``key`` until the handle or the transport is closed."""
        ...

    def liveliness_subscribe(
        self,
        key_expr: str,
        on_join: Callable[[str], object],
        on_leave: Callable[[str], object],
        history: bool = True,
    ) -> Closeable:
        """Call ``on_join(key)``/``on_leave(key)`` as tokens matching ``key_expr`` appear and vanish;
        with ``history`` the tokens alive now are reported as joins first."""
        ...

    def close(self) -> None:
        """Undeclare everything, join the transport's threads; idempotent."""
        ...

    def __enter__(self) -> Self: ...

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None: ...
