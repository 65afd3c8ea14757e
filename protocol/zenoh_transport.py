"""Zenoh implementation of the transport, plus the connection flags every process CLI shares.

Usage::

    parser = argparse.ArgumentParser()
    add_connection_args(parser)                 # --connect, --listen, --zenoh-config, --mode, ...
    args = parser.parse_args()
    with ZenohTransport.open(config_from_args(args)) as t:
        t.subscribe(t.keys.experience(), ExperienceBatch, store.add)

Receiving: each subscription, queryable and liveliness subscription gets a zenoh ``FifoChannel`` of
``channel_capacity`` samples drained by one worker thread that decodes, validates and calls the handler.
Zenoh's callback never runs Python code of ours, so it cannot block or raise in a zenoh thread. A full
FifoChannel blocks zenoh's receive path, which pushes back through TCP to BLOCK publishers: delivery is
lossless and the publisher slows to the consumer's pace (measured: a callback that drops into a bounded
``queue.Queue`` instead lost 95 % of a fast BLOCK stream). Two limits remain, both covered by the
ack/outbox contract of docs/reference/protocol.md:

* a handler stalled for longer than zenoh's ``transport/link/tx/queue/congestion_control/block/
  wait_before_close`` (5 s by default) makes the publisher's zenoh close the link: what was in flight is
  lost silently and the link is re-established;
* messages published while no subscriber is connected are not stored anywhere.

Memory held per subscription is bounded by ``channel_capacity`` × the largest payload.

Over 400 lines: everything that touches a zenoh session (declaring, the bounded channels and their workers, the
watchdog that reopens a broken session, closing) in one class, so that no other module holds zenoh's objects and
the session's life is read in one place.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from types import TracebackType
from typing import Any, Self

import zenoh

from protocol.codec import encode
from protocol.keys import DEFAULT_KEYS, ENCODING, KeySpace
from protocol.messages import Message
from protocol.security import MAX_MESSAGE_BYTES
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

log = logging.getLogger(__name__)

MODES = ("peer", "client", "router")
DEFAULT_CHANNEL_CAPACITY = 32
REOPEN_AFTER_LEASES = 2
"""A client session without a router for this many leases is closed and opened anew."""
WATCH_INTERVAL_S = 1.0
SHM_POOL_BYTES = 4 * 2**20
"""Zenoh's shared-memory pool per session (its default: 16 MiB). Every process of a one-host run maps its own pool
and each peer's it receives from, all of it resident once used round-robin; an experience batch is about 1 MiB."""
_JOIN_TIMEOUT_S = 10.0


def zenoh_config(
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    mode: str | None = None,
    config_file: str | None = None,
    multicast_scouting: bool | None = None,
) -> zenoh.Config:
    """Build a zenoh Config: ``config_file`` (JSON5) if given, then these settings on top.

    ``mode=None`` keeps the file's mode, or is ``peer`` without a file. ``multicast_scouting=None`` keeps the
    file's setting, or turns scouting off without a file: explicit endpoints are what works across machines and
    containers. Clients retry their router forever (``connect/timeout_ms = -1``) instead of failing when started
    before it. Zenoh's largest message is capped at :data:`~protocol.security.MAX_MESSAGE_BYTES` (a file may set
    less), so an oversize message is dropped while it is reassembled, before it can fill memory.

    >>> conf = zenoh_config(connect=["tcp/10.0.0.1:7447"], mode="client")
    """
    if mode is not None and mode not in MODES:
        raise ValueError(f"mode {mode!r} not one of {MODES}")
    if config_file:
        # Zenoh's own error for an unreadable file names neither the file nor, in words, the cause: opening it here
        # first makes it an OSError that names both (a container user that cannot read a mounted secret, say).
        with open(config_file, "rb"):
            pass
    conf = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    if mode is not None or not config_file:
        conf.insert_json5("mode", json.dumps(mode or "peer"))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if multicast_scouting is not None or not config_file:
        conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
    if mode == "client":
        conf.insert_json5("connect/timeout_ms", "-1")
    if not config_file:
        conf.insert_json5("transport/shared_memory/transport_optimization/pool_size", str(SHM_POOL_BYTES))
    limit = min(int(conf.get_json("transport/link/rx/max_message_size")), MAX_MESSAGE_BYTES)
    conf.insert_json5("transport/link/rx/max_message_size", str(limit))
    return conf


def add_connection_args(parser: argparse.ArgumentParser) -> None:
    """Add the zenoh connection flags shared by every process CLI (read back by :func:`config_from_args`)."""
    group = parser.add_argument_group("zenoh connection")
    group.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to connect to (repeatable; default: none, or as in --zenoh-config)",
    )
    group.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="endpoint to listen on (repeatable; default: none, or as in --zenoh-config)",
    )
    group.add_argument(
        "--zenoh-config", metavar="FILE", help="zenoh JSON5 config file; the flags above override it (default: none)"
    )
    group.add_argument(
        "--mode", choices=MODES, default=None, help="zenoh session mode (default: peer, or as in --zenoh-config)"
    )
    group.add_argument(
        "--multicast-scouting",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="discover peers by UDP multicast (default: off, or as in --zenoh-config)",
    )
    group.add_argument(
        "--namespace",
        default="",
        type=_namespace,
        help="key prefix isolating this run from others on the same network (default: none)",
    )


def _namespace(text: str) -> str:
    """``--namespace`` checked as it is parsed, so that every process (the router too) refuses the same ones."""
    try:
        KeySpace(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).replace("namespace chunk: ", "")) from None
    return text


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    """The zenoh Config selected by the flags of :func:`add_connection_args`."""
    return zenoh_config(args.connect, args.listen, args.mode, args.zenoh_config, args.multicast_scouting)


def keys_from_args(args: argparse.Namespace) -> KeySpace:
    """The KeySpace selected by ``--namespace``."""
    return KeySpace(args.namespace)


class _Pump:
    """A zenoh entity with a FifoChannel handler and the worker thread that drains it. The entity is
    ``declare(session)``: declared again on each session the transport reopens (``detach``, then ``attach``), the same
    worker draining it."""

    def __init__(
        self,
        name: str,
        declare: Callable[[zenoh.Session], Any],
        session: zenoh.Session | None,
        on_item: Callable[[Any], None],
        stats: TransportStats,
    ) -> None:
        self._declare = declare
        self._on_item = on_item
        self._stats = stats
        self._cond = threading.Condition()
        self._entity: Any = None if session is None else declare(session)
        self._closed = False
        # Daemon only as a last resort: close() joins it; a forgotten one must not keep the process alive.
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            with self._cond:
                while self._entity is None and not self._closed:
                    self._cond.wait()
                entity = self._entity
                if entity is None:
                    return  # closed while detached
            try:
                item = entity.handler.recv()
            except zenoh.ZError:  # the channel is closed (entity undeclared) and drained
                with self._cond:
                    if self._closed:
                        return
                    if self._entity is entity:
                        self._entity = None  # closed under us: wait for the next attach instead of spinning
                continue
            run_handler(self._stats, self._thread.name, self._on_item, item)

    def detach(self) -> None:
        """Undeclare the entity (the session is going away); the worker drains it and waits for :meth:`attach`."""
        with self._cond:
            entity, self._entity = self._entity, None
        if entity is not None:
            entity.undeclare()

    def attach(self, session: zenoh.Session) -> None:
        """Declare the entity on ``session`` unless it is declared already."""
        with self._cond:
            if self._closed or self._entity is not None:
                return
            self._entity = self._declare(session)
            self._cond.notify_all()

    def close(self) -> None:
        """Undeclare the entity, let the worker drain the channel and join it; idempotent."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            entity, self._entity = self._entity, None
            self._cond.notify_all()
        if entity is not None:
            entity.undeclare()
        if threading.current_thread() is not self._thread:
            self._thread.join(_JOIN_TIMEOUT_S)
            if self._thread.is_alive():
                log.warning("worker %s still busy %.0f s after close", self._thread.name, _JOIN_TIMEOUT_S)


class _Token:
    """A liveliness token, declared again on each session the transport reopens."""

    def __init__(self, key: str, session: zenoh.Session | None) -> None:
        self._key = key
        self._lock = threading.Lock()
        self._closed = False
        self._token: zenoh.LivelinessToken | None = None
        if session is not None:
            self.attach(session)

    def detach(self) -> None:
        with self._lock:
            token, self._token = self._token, None
        if token is not None:
            token.undeclare()

    def attach(self, session: zenoh.Session) -> None:
        with self._lock:
            if not self._closed and self._token is None:
                self._token = session.liveliness().declare_token(self._key)

    def close(self) -> None:
        """Undeclare the token; idempotent."""
        with self._lock:
            self._closed = True
        self.detach()


def _reopen_after_s(conf: zenoh.Config) -> float | None:
    """How long a client session may see no router before it is reopened (two leases), or None: not a client with
    endpoints to connect to, so nothing to reopen towards."""
    if json.loads(conf.get_json("mode")) != "client" or not json.loads(conf.get_json("connect/endpoints")):
        return None
    return REOPEN_AFTER_LEASES * int(conf.get_json("transport/link/tx/lease")) / 1000


class ZenohTransport:
    """A :class:`~protocol.transport.Transport` over a zenoh session.

    ``ZenohTransport(session)`` borrows a session the caller closes; :meth:`open` owns one and, for a client,
    watches it: a session that sees no router for two leases is closed and opened anew, everything declared on it
    declared again (see :meth:`_watch`).
    """

    def __init__(
        self,
        session: zenoh.Session,
        keys: KeySpace = DEFAULT_KEYS,
        *,
        channel_capacity: int = DEFAULT_CHANNEL_CAPACITY,
        own_session: bool = False,
    ) -> None:
        self.session = session
        self.keys = keys
        self.stats = TransportStats()
        self._capacity = channel_capacity
        self._own_session = own_session
        self._lock = threading.Lock()
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._handles: list[_Pump | _Token] = []
        self._closed = False
        self._reopening = False
        """While True the session is being replaced: publications are dropped (as zenoh drops them while no router
        is connected), declarations wait for the new session."""
        self._stop = threading.Event()
        self._watchdog: threading.Thread | None = None
        self.reopened = 0
        """Sessions opened anew by the watchdog."""

    @classmethod
    def open(
        cls, conf: zenoh.Config, keys: KeySpace = DEFAULT_KEYS, *, reopen_after_s: float | None = None, **kwargs: Any
    ) -> ZenohTransport:
        """Open a zenoh session with ``conf`` that :meth:`close` will close. A client's session is reopened after
        ``reopen_after_s`` seconds without a router (default: two of ``conf``'s leases); another's never is."""
        transport = cls(zenoh.open(conf), keys, own_session=True, **kwargs)
        after = _reopen_after_s(conf)
        if after is not None:
            after = after if reopen_after_s is None else reopen_after_s
            transport._watchdog = threading.Thread(
                target=transport._watch, args=(conf, after), name="zenoh-session-watchdog", daemon=True
            )
            transport._watchdog.start()
        return transport

    def _check_open(self) -> None:
        if self._closed:
            raise TransportClosed("transport is closed")

    def _watch(self, conf: zenoh.Config, after: float) -> None:
        """Reopen the session once it has seen no router for ``after`` seconds.

        Why: zenoh 1.10.2 can leave a client's session connected in name only. Seen in the chaos suite (an actor
        partitioned past the lease, then healed): the session reconnected, received the learner's policies and
        acknowledgements, and put nothing on the wire (5 KB in minutes of re-sends) while ``routers_zid()`` stayed
        empty. That fits the race zenoh issue #1886 describes: the old transport, its sending stuck in the cut-off
        socket, finishes closing only after the new one opened, and takes the new one's routing with it. Nothing in
        the session mends it, so a client without a router for two leases starts afresh; after a real outage this
        costs one more connection, once the router is back.
        """
        lost_since: float | None = None
        while not self._stop.wait(WATCH_INTERVAL_S):
            try:
                connected = bool(self.session.info.routers_zid())
            except zenoh.ZError:
                return  # closed under us
            now = time.monotonic()
            if connected:
                lost_since = None
            elif lost_since is None:
                lost_since = now
            elif now - lost_since >= after:
                log.warning("no router for %.0f s: closing the zenoh session and opening it anew", now - lost_since)
                self._reopen(conf)
                lost_since = None

    def _reopen(self, conf: zenoh.Config) -> None:
        """Replace the session by a new one with ``conf`` and declare everything again on it."""
        with self._lock:
            if self._closed:
                return
            self._reopening = True
            old, handles = self.session, list(self._handles)
            publishers, self._publishers = list(self._publishers.values()), {}
        # The old session is broken: what fails in undeclaring on it or closing it is of no further concern.
        with contextlib.suppress(zenoh.ZError):
            for handle in handles:
                handle.detach()
            for pub in publishers:
                pub.undeclare()
            old.close()
        while True:
            try:
                new = zenoh.open(conf)  # a client retries its router until it answers
                break
            except zenoh.ZError as exc:
                log.error("reopening the zenoh session failed (retrying): %s", exc)
                if self._stop.wait(WATCH_INTERVAL_S):
                    return
        with self._lock:
            if self._closed:
                new.close()
                return
            self.session, self._reopening = new, False
            handles = list(self._handles)
        for handle in handles:
            handle.attach(new)
        self.reopened += 1
        log.info("zenoh session reopened (%d so far): %d declarations renewed", self.reopened, len(handles))

    def _publisher(self, key: str) -> zenoh.Publisher | None:
        """The publisher of ``key``, declared at its first use; None while the session is being reopened."""
        with self._lock:
            self._check_open()
            if self._reopening:
                return None
            pub = self._publishers.get(key)
            if pub is None:
                qos = self.keys.qos(key)
                pub = self.session.declare_publisher(
                    key,
                    encoding=ENCODING,
                    congestion_control=qos.congestion_control,
                    priority=qos.priority,
                    express=qos.express,
                    reliability=qos.reliability,
                )
                self._publishers[key] = pub
            return pub

    def _add(self, make: Callable[[zenoh.Session | None], _Pump | _Token]) -> Closeable:
        """``make(session)``, declared on the session now, or detached (``make(None)``) while it is being reopened:
        the reopening then attaches it to the new one."""
        with self._lock:
            self._check_open()
            handle = make(None if self._reopening else self.session)
            self._handles.append(handle)
        return handle

    def publish(self, key: str, msg: Message) -> None:
        self.keys.check_message(key, msg)  # our own bug is caught here, before the wire
        data = encode(msg)
        pub = self._publisher(key)
        if pub is None:
            log.debug("no session while it is reopened: a message on %s dropped", key)
            return
        try:
            pub.put(data)
        except zenoh.ZError:
            with self._lock:
                replaced = self._publishers.get(key) is not pub
            if not replaced:
                raise
            log.debug("the session was reopened during a put on %s: the message dropped", key)
            return
        self.stats.count_published()

    def subscribe(
        self, key_expr: str, msg_type: type[M], handler: Callable[[M], object], on_reject: Rejected | None = None
    ) -> Closeable:
        self._check_open()

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            deliver(self.keys, self.stats, key, sample.payload.to_bytes(), msg_type, handler, on_reject)

        def declare(session: zenoh.Session) -> Any:
            return session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(self._capacity))

        return self._add(lambda session: _Pump(f"zenoh-sub {key_expr}", declare, session, on_sample, self.stats))

    def has_subscribers(self, key: str) -> bool:
        # zenoh 1.10's stub says bool, but the value is a MatchingStatus object, which is always truthy.
        pub = self._publisher(key)
        status: Any = None if pub is None else pub.matching_status
        return status is not None and bool(status.matching)

    def declare_queryable(self, key: str, fn: Callable[[], Message | None]) -> Closeable:
        self._check_open()

        def on_query(query: zenoh.Query) -> None:
            with query:  # leaving the block finalises the query, so the asker stops waiting
                msg = fn()
                if msg is not None:
                    query.reply(key, encode(msg), encoding=ENCODING)

        def declare(session: zenoh.Session) -> Any:
            return session.declare_queryable(key, zenoh.handlers.FifoChannel(self._capacity))

        return self._add(lambda session: _Pump(f"zenoh-queryable {key}", declare, session, on_query, self.stats))

    def get(self, key_expr: str, msg_type: type[M], timeout: float = 2.0) -> list[M]:
        self._check_open()
        replies: list[M] = []
        if self._reopening:
            return replies  # no session to ask: as if nobody answered
        for reply in self.session.get(key_expr, timeout=timeout):
            sample = reply.ok
            if sample is None:
                log.warning("error reply to get %s: %s", key_expr, reply.err)
                continue
            msg = accept(self.keys, self.stats, str(sample.key_expr), sample.payload.to_bytes(), msg_type)
            if msg is not None:
                replies.append(msg)
        return replies

    def liveliness_token(self, key: str) -> Closeable:
        return self._add(lambda session: _Token(key, session))

    def liveliness_subscribe(
        self,
        key_expr: str,
        on_join: Callable[[str], object],
        on_leave: Callable[[str], object],
        history: bool = True,
    ) -> Closeable:
        self._check_open()

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            (on_join if sample.kind == zenoh.SampleKind.PUT else on_leave)(key)

        def declare(session: zenoh.Session) -> Any:
            channel: zenoh.handlers.FifoChannel[zenoh.Sample] = zenoh.handlers.FifoChannel(self._capacity)
            return session.liveliness().declare_subscriber(key_expr, channel, history=history)

        return self._add(lambda session: _Pump(f"zenoh-liveliness {key_expr}", declare, session, on_sample, self.stats))

    def close(self) -> None:
        """Undeclare everything, join the workers, then close the session if this transport owns it."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            handles, self._handles = self._handles, []
            publishers, self._publishers = list(self._publishers.values()), {}
            reopening = self._reopening
        self._stop.set()
        for handle in handles:
            handle.close()
        for pub in publishers:
            pub.undeclare()
        # While the watchdog reopens the session, the old one is closed already and the watchdog closes the new one
        # once it opens (it may wait for a router indefinitely: it is not joined then).
        if not reopening:
            if self._watchdog is not None:
                self._watchdog.join()
            if self._own_session:
                self.session.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
