"""The ENNC-QL wire protocol: typed messages, the msgpack codec, key expressions + QoS, and transports.

This package owns everything that crosses a process boundary; the format is specified for other
languages in docs/reference/protocol.md. Typical use::

    from protocol import ExperienceBatch, ZenohTransport, zenoh_config

    with ZenohTransport.open(zenoh_config(connect=["tcp/127.0.0.1:7447"])) as t:
        t.publish(t.keys.experience("actor-0"), batch)
"""

import importlib
from typing import TYPE_CHECKING, Any

from protocol.codec import MAX_PAYLOAD_BYTES, decode, decode_as, encode, peek_sequence
from protocol.messages import (
    N_ACTIONS,
    ROLES,
    SCHEMA_VERSION,
    Ack,
    ActorView,
    ExperienceBatch,
    Header,
    IdentityMismatch,
    InvalidValues,
    MalformedMessage,
    Message,
    OversizePayload,
    PolicyUpdate,
    ProtocolError,
    QTableIncrement,
    Reject,
    SchemaVersionMismatch,
    Status,
    UnexpectedMessageType,
    check_id,
    message_equal,
)

# Key spaces, QoS and the transports need zenoh; they load on first use (PEP 562), so code that only builds or
# encodes messages (the algorithm package's wire conversions) never imports it.
_LAZY = {
    "DEFAULT_KEYS": "protocol.keys",
    "QOS": "protocol.keys",
    "Channel": "protocol.keys",
    "KeySpace": "protocol.keys",
    "QoS": "protocol.keys",
    "InMemoryBus": "protocol.memory",
    "InMemoryTransport": "protocol.memory",
    "Closeable": "protocol.transport",
    "Transport": "protocol.transport",
    "TransportClosed": "protocol.transport",
    "TransportStats": "protocol.transport",
    "ZenohTransport": "protocol.zenoh_transport",
    "add_connection_args": "protocol.zenoh_transport",
    "config_from_args": "protocol.zenoh_transport",
    "keys_from_args": "protocol.zenoh_transport",
    "zenoh_config": "protocol.zenoh_transport",
}

if TYPE_CHECKING:
    from protocol.keys import DEFAULT_KEYS, QOS, Channel, KeySpace, QoS
    from protocol.memory import InMemoryBus, InMemoryTransport
    from protocol.transport import Closeable, Transport, TransportClosed, TransportStats
    from protocol.zenoh_transport import (
        ZenohTransport,
        add_connection_args,
        config_from_args,
        keys_from_args,
        zenoh_config,
    )


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'protocol' has no attribute {name!r}")


__all__ = [
    "DEFAULT_KEYS",
    "MAX_PAYLOAD_BYTES",
    "N_ACTIONS",
    "QOS",
    "ROLES",
    "SCHEMA_VERSION",
    "Ack",
    "ActorView",
    "Channel",
    "Closeable",
    "ExperienceBatch",
    "Header",
    "IdentityMismatch",
    "InMemoryBus",
    "InMemoryTransport",
    "InvalidValues",
    "KeySpace",
    "MalformedMessage",
    "Message",
    "OversizePayload",
    "PolicyUpdate",
    "ProtocolError",
    "QTableIncrement",
    "QoS",
    "Reject",
    "SchemaVersionMismatch",
    "Status",
    "Transport",
    "TransportClosed",
    "TransportStats",
    "UnexpectedMessageType",
    "ZenohTransport",
    "add_connection_args",
    "check_id",
    "config_from_args",
    "decode",
    "decode_as",
    "encode",
    "keys_from_args",
    "message_equal",
    "peek_sequence",
    "zenoh_config",
]
