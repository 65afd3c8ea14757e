"""The ENNC-QL wire protocol: typed messages, the msgpack codec, key expressions + QoS, and transports.

This package owns everything that crosses a process boundary; the format is specified for other
languages in docs/protocol.md. Typical use::

    from protocol import ExperienceBatch, ZenohTransport, zenoh_config

    with ZenohTransport.open(zenoh_config(connect=["tcp/127.0.0.1:7447"])) as t:
        t.publish(t.keys.experience("actor-0"), batch)
"""

from protocol.codec import MAX_PAYLOAD_BYTES, decode, decode_as, encode
from protocol.keys import DEFAULT_KEYS, QOS, Channel, KeySpace, QoS
from protocol.memory import InMemoryBus, InMemoryTransport
from protocol.messages import (
    FEATURIZER_DIMS,
    N_ACTIONS,
    ROLES,
    SCHEMA_VERSION,
    Ack,
    ExperienceBatch,
    InvalidValues,
    MalformedMessage,
    Message,
    OversizePayload,
    PolicyUpdate,
    ProtocolError,
    QTableIncrement,
    SchemaVersionMismatch,
    Status,
    UnexpectedMessageType,
    check_id,
    message_equal,
)
from protocol.transport import Closeable, Transport, TransportClosed, TransportStats
from protocol.zenoh_transport import (
    ZenohTransport,
    add_connection_args,
    config_from_args,
    keys_from_args,
    zenoh_config,
)

__all__ = [
    "DEFAULT_KEYS",
    "FEATURIZER_DIMS",
    "MAX_PAYLOAD_BYTES",
    "N_ACTIONS",
    "QOS",
    "ROLES",
    "SCHEMA_VERSION",
    "Ack",
    "Channel",
    "Closeable",
    "ExperienceBatch",
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
    "zenoh_config",
]
