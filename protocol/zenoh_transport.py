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
ack/outbox contract of docs/protocol.md:

* a handler stalled for longer than zenoh's ``transport/link/tx/queue/congestion_control/block/
  wait_before_close`` (5 s by default) makes the publisher's zenoh close the link: what was in flight is
  lost silently and the link is re-established;
* messages published while no subscriber is connected are not stored anywhere.

Memory held per subscription is bounded by ``channel_capacity`` × the largest payload.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
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
    """A zenoh entity with a FifoChannel handler and the worker thread that drains it."""

    def __init__(self, name: str, entity: Any, on_item: Callable[[Any], None], stats: TransportStats) -> None:
        self._entity = entity
        self._on_item = on_item
        self._stats = stats
        self._closed = False
        # Daemon only as a last resort: close() joins it; a forgotten one must not keep the process alive.
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            try:
                item = self._entity.handler.recv()
            except zenoh.ZError:
                return  # the channel is closed (entity undeclared) and drained
            run_handler(self._stats, self._thread.name, self._on_item, item)

    def close(self) -> None:
        """Undeclare the entity, let the worker drain the channel and join it; idempotent."""
        if self._closed:
            return
        self._closed = True
        self._entity.undeclare()
        if threading.current_thread() is not self._thread:
            self._thread.join(_JOIN_TIMEOUT_S)
            if self._thread.is_alive():
                log.warning("worker %s still busy %.0f s after close", self._thread.name, _JOIN_TIMEOUT_S)


class _Token:
    def __init__(self, token: zenoh.LivelinessToken) -> None:
        self._token: zenoh.LivelinessToken | None = token

    def close(self) -> None:
        """Undeclare the token; idempotent."""
        token, self._token = self._token, None
        if token is not None:
            token.undeclare()


class ZenohTransport:
    """A :class:`~protocol.transport.Transport` over a zenoh session.

    ``ZenohTransport(session)`` borrows a session the caller closes; :meth:`open` owns one.
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

    @classmethod
    def open(cls, conf: zenoh.Config, keys: KeySpace = DEFAULT_KEYS, **kwargs: Any) -> ZenohTransport:
        """Open a zenoh session with ``conf`` that :meth:`close` will close."""
        return cls(zenoh.open(conf), keys, own_session=True, **kwargs)

    def _check_open(self) -> None:
        if self._closed:
            raise TransportClosed("transport is closed")

    def _publisher(self, key: str) -> zenoh.Publisher:
        with self._lock:
            self._check_open()
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

    def _add(self, handle: _Pump | _Token) -> Closeable:
        with self._lock:
            if self._closed:
                handle.close()
                raise TransportClosed("transport is closed")
            self._handles.append(handle)
        return handle

    def publish(self, key: str, msg: Message) -> None:
        self.keys.check_message(key, msg)  # our own bug is caught here, before the wire
        data = encode(msg)
        self._publisher(key).put(data)
        self.stats.count_published()

    def subscribe(
        self, key_expr: str, msg_type: type[M], handler: Callable[[M], object], on_reject: Rejected | None = None
    ) -> Closeable:
        self._check_open()

        def on_sample(sample: zenoh.Sample) -> None:
            key = str(sample.key_expr)
            deliver(self.keys, self.stats, key, sample.payload.to_bytes(), msg_type, handler, on_reject)

        sub = self.session.declare_subscriber(key_expr, zenoh.handlers.FifoChannel(self._capacity))
        return self._add(_Pump(f"zenoh-sub {key_expr}", sub, on_sample, self.stats))

    def refresh_publishers(self) -> None:
        # Seen in the chaos suite (zenoh 1.10.2, a client behind a partition past the lease): after the session
        # reconnected, its subscribers and liveliness came back, but the publishers declared before the cut put
        # nothing more on the wire (5 KB sent in 6 minutes of re-sends). Dropping them lets the next publish
        # declare new ones; a publisher another thread is using now stays alive until that put returns.
        with self._lock:
            self._publishers.clear()

    def has_subscribers(self, key: str) -> bool:
        # zenoh 1.10's stub says bool, but the value is a MatchingStatus object, which is always truthy.
        status: Any = self._publisher(key).matching_status
        return bool(status.matching)

    def declare_queryable(self, key: str, fn: Callable[[], Message | None]) -> Closeable:
        self._check_open()

        def on_query(query: zenoh.Query) -> None:
            with query:  # leaving the block finalises the query, so the asker stops waiting
                msg = fn()
                if msg is not None:
                    query.reply(key, encode(msg), encoding=ENCODING)

        queryable = self.session.declare_queryable(key, zenoh.handlers.FifoChannel(self._capacity))
        return self._add(_Pump(f"zenoh-queryable {key}", queryable, on_query, self.stats))

    def get(self, key_expr: str, msg_type: type[M], timeout: float = 2.0) -> list[M]:
        self._check_open()
        replies: list[M] = []
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
        self._check_open()
        return self._add(_Token(self.session.liveliness().declare_token(key)))

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

        sub = self.session.liveliness().declare_subscriber(
            key_expr, zenoh.handlers.FifoChannel(self._capacity), history=history
        )
        return self._add(_Pump(f"zenoh-liveliness {key_expr}", sub, on_sample, self.stats))

    def close(self) -> None:
        """Undeclare everything, join the workers, then close the session if this transport owns it."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            handles, self._handles = self._handles, []
            publishers, self._publishers = list(self._publishers.values()), {}
        for handle in handles:
            handle.close()
        for pub in publishers:
            pub.undeclare()
        if self._own_session:
            self.session.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
