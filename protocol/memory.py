"""In-process transport for serial mode and fast tests.

An :class:`InMemoryBus` plays the network; each :class:`InMemoryTransport` on it plays one zenoh session.
Delivery is synchronous (the handler runs inside ``publish``), every payload goes through the codec, and
key matching is zenoh's own (``zenoh.KeyExpr.intersects``), so ``*``/``**`` behave exactly as on zenoh::

    bus = InMemoryBus()
    with InMemoryTransport(bus) as learner, InMemoryTransport(bus) as actor:
        learner.subscribe(learner.keys.experience(), ExperienceBatch, received.append)
        actor.publish(actor.keys.experience("actor-0"), batch)   # received == [decoded copy of batch]

Closing a transport undeclares its subscriptions, queryables and tokens (liveliness subscribers see a
leave), as closing a zenoh session does. Handlers may publish or declare; delivery then nests.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any, Literal, Self, get_args

import zenoh

from protocol.codec import encode
from protocol.keys import DEFAULT_KEYS, KeySpace
from protocol.messages import Message
from protocol.transport import (
    Closeable,
    M,
    Rejected,
    TransportClosed,
    TransportStats,
    accept,
    deliver,
    run_handler,
)

_Kind = Literal["sub", "queryable", "token", "liveliness_sub"]


def _ignore(*_: object) -> None:
    """Placeholder callback of entities that have none."""


@dataclass(eq=False)
class _Entity:
    """Something declared on the bus; ``close()`` undeclares it.

    ``handler`` is the message handler of a ``sub``, the reply function of a ``queryable`` and the
    ``on_join`` of a ``liveliness_sub``.
    """

    owner: InMemoryTransport
    kind: _Kind
    key: str
    msg_type: type[Any] = object
    handler: Callable[..., Any] = _ignore
    on_leave: Callable[[str], object] = _ignore
    on_reject: Rejected | None = None

    def __post_init__(self) -> None:
        self.key_expr = zenoh.KeyExpr(self.key)  # raises zenoh.ZError on an invalid key expression

    def close(self) -> None:
        self.owner._undeclare(self)


class InMemoryBus:
    """The shared in-process 'network' of several :class:`InMemoryTransport` s."""

    def __init__(self) -> None:
        # Entities are only read through snapshots taken under the lock, so handlers may declare or publish.
        self._lock = threading.Lock()
        self._entities: dict[_Kind, list[_Entity]] = {kind: [] for kind in get_args(_Kind)}

    def matching(self, kind: _Kind, key: str) -> list[_Entity]:
        """The declared entities of ``kind`` whose key expression intersects ``key``."""
        with self._lock:
            return [e for e in self._entities[kind] if e.key_expr.intersects(key)]

    def add(self, entity: _Entity) -> None:
        with self._lock:
            self._entities[entity.kind].append(entity)

    def remove(self, entity: _Entity) -> bool:
        """Remove ``entity``; False if it was not declared (already closed)."""
        with self._lock:
            if entity not in self._entities[entity.kind]:
                return False
            self._entities[entity.kind].remove(entity)
            return True


class InMemoryTransport:
    """A :class:`~protocol.transport.Transport` on an :class:`InMemoryBus` (a private one by default)."""

    def __init__(self, bus: InMemoryBus | None = None, keys: KeySpace = DEFAULT_KEYS) -> None:
        self.bus = bus if bus is not None else InMemoryBus()
        self.keys = keys
        self.stats = TransportStats()
        self._entities: list[_Entity] = []
        self._closed = False

    def _check_open(self) -> None:
        if self._closed:
            raise TransportClosed("transport is closed")

    def _declare(self, entity: _Entity) -> Closeable:
        self._check_open()
        self.bus.add(entity)
        self._entities.append(entity)
        return entity

    def _undeclare(self, entity: _Entity) -> None:
        if not self.bus.remove(entity):
            return
        self._entities.remove(entity)
        if entity.kind == "token":
            for sub in self.bus.matching("liveliness_sub", entity.key):
                run_handler(sub.owner.stats, f"on_leave({entity.key})", sub.on_leave, entity.key)

    def publish(self, key: str, msg: Message) -> None:
        self._check_open()
        self.keys.check_message(key, msg)  # our own bug is caught here, before the wire
        data = encode(msg)
        self.stats.count_published()
        self._route(key, data)

    def inject_raw(self, key: str, payload: bytes) -> None:
        """Deliver raw bytes to the subscribers of ``key`` as if a peer had sent them (fault injection)."""
        self._check_open()
        self._route(key, payload)

    def _route(self, key: str, data: bytes) -> None:
        for sub in self.bus.matching("sub", key):
            deliver(sub.owner.keys, sub.owner.stats, key, data, sub.msg_type, sub.handler, sub.on_reject)

    def subscribe(
        self, key_expr: str, msg_type: type[M], handler: Callable[[M], object], on_reject: Rejected | None = None
    ) -> Closeable:
        return self._declare(_Entity(self, "sub", key_expr, msg_type, handler, on_reject=on_reject))

    def has_subscribers(self, key: str) -> bool:
        return bool(self.bus.matching("sub", key))

    def declare_queryable(self, key: str, fn: Callable[[], Message | None]) -> Closeable:
        return self._declare(_Entity(self, "queryable", key, handler=fn))

    def get(self, key_expr: str, msg_type: type[M], timeout: float = 2.0) -> list[M]:
        """Ask every matching queryable synchronously (``timeout`` is unused: nothing can be late)."""
        self._check_open()
        replies: list[M] = []
        for queryable in self.bus.matching("queryable", key_expr):
            # As on zenoh, a failing reply function (or an invalid reply) is the queryable owner's handler error.
            answers: list[bytes] = []
            run_handler(queryable.owner.stats, f"queryable {queryable.key}", self._ask, queryable, answers)
            for data in answers:
                msg = accept(self.keys, self.stats, queryable.key, data, msg_type)
                if msg is not None:
                    replies.append(msg)
        return replies

    @staticmethod
    def _ask(queryable: _Entity, answers: list[bytes]) -> None:
        answer = queryable.handler()
        if answer is not None:
            answers.append(encode(answer))

    def liveliness_token(self, key: str) -> Closeable:
        token = self._declare(_Entity(self, "token", key))
        for sub in self.bus.matching("liveliness_sub", key):
            run_handler(sub.owner.stats, f"on_join({key})", sub.handler, key)
        return token

    def liveliness_subscribe(
        self,
        key_expr: str,
        on_join: Callable[[str], object],
        on_leave: Callable[[str], object],
        history: bool = True,
    ) -> Closeable:
        sub = self._declare(_Entity(self, "liveliness_sub", key_expr, handler=on_join, on_leave=on_leave))
        if history:
            for token in self.bus.matching("token", key_expr):
                run_handler(self.stats, f"on_join({token.key})", on_join, token.key)
        return sub

    def close(self) -> None:
        """Undeclare everything this transport declared (tokens last, like a closing session)."""
        if self._closed:
            return
        for entity in sorted(self._entities, key=lambda e: e.kind == "token"):
            entity.close()
        self._closed = True

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
