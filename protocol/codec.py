"""The one msgpack codec of the ENNC-QL wire protocol (layout specified in docs/reference/protocol.md).

Envelope: a msgpack array ``[schema_version, type_tag, fields]`` where ``fields`` maps each field name
to its value; a numpy array travels as ``[dtype_name, shape, raw_little_endian_bytes]``. No pickle, no
msgpack extension types.

Usage::

    data = encode(batch)                        # bytes; validates first
    msg = decode(data)                          # any Message; validates; raises only ProtocolError
    batch = decode_as(data, ExperienceBatch)    # UnexpectedMessageType if it is another type

Arrays handed out by :func:`decode` are **read-only** views on the decoded msgpack ``bin`` objects (no
copy beyond the one msgpack makes): call ``.copy()`` to mutate.
"""

from __future__ import annotations

import logging
import math
import struct
from typing import Any, TypeVar

import msgpack
import numpy as np

from protocol.messages import (
    MESSAGE_TYPES,
    SCHEMA_VERSION,
    FieldSpec,
    MalformedMessage,
    Message,
    OversizePayload,
    ProtocolError,
    SchemaVersionMismatch,
    UnexpectedMessageType,
    check_id,
    field_specs,
)

log = logging.getLogger(__name__)

MAX_PAYLOAD_BYTES = 64 * 1024 * 1024
"""Largest payload :func:`encode` produces and :func:`decode` accepts."""

_DTYPE_NAMES = ("bool", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64")
WIRE_DTYPES: dict[str, np.dtype[Any]] = {name: np.dtype(name).newbyteorder("<") for name in _DTYPE_NAMES}
"""Allow-list of array dtype names on the wire; every multi-byte dtype is little-endian."""

_MAX_NDIM = 4
# No legitimate string (ids, names, field and dtype names) comes near this; capping it, the container
# sizes and ext types bounds what a hostile payload can make the unpacker allocate before validation.
_UNPACK_LIMITS = {"max_str_len": 256, "max_array_len": 64, "max_map_len": 128, "max_ext_len": 0}

M = TypeVar("M", bound=Message)

_WIRE_NAMES = {dtype: name for name, dtype in WIRE_DTYPES.items()}


def _bin_header(n: int) -> bytes:
    # The smallest msgpack bin header that holds n bytes, as msgpack itself writes it (bin 8, 16 or 32).
    if n < 1 << 8:
        return struct.pack(">BB", 0xC4, n)
    if n < 1 << 16:
        return struct.pack(">BH", 0xC5, n)
    return struct.pack(">BI", 0xC6, n)


def encode(msg: Message, *, max_bytes: int = MAX_PAYLOAD_BYTES) -> bytes:
    """Validate ``msg`` and serialise it; raise :class:`OversizePayload` beyond ``max_bytes``."""
    msg.validate()
    # The document is assembled from msgpack-packed pieces around each array's raw bytes, then joined: every array
    # is copied exactly once, straight into the payload (msgpack's own packb grows a buffer and copies it out again,
    # which costs two more passes over ~1 MB per experience batch). The bytes are those packb would write.
    specs = field_specs(type(msg))
    pack = msgpack.Packer(use_bin_type=True)
    parts: list[bytes | memoryview] = [
        pack.pack_array_header(3),
        pack.pack(SCHEMA_VERSION),
        pack.pack(msg.TAG),
        pack.pack_map_header(len(specs)),
    ]
    for name, spec in specs.items():
        value = getattr(msg, name)
        parts.append(pack.pack(name))
        if spec.kind == "array":
            # Validation has pinned the dtype to a little-endian one of the allow-list.
            flat = np.ascontiguousarray(value).reshape(-1).view(np.uint8)
            parts += [
                pack.pack_array_header(3),
                pack.pack(_WIRE_NAMES[value.dtype]),
                pack.pack(list(value.shape)),
                _bin_header(flat.nbytes),
                flat.data,
            ]
        elif spec.kind == "counters":
            parts.append(pack.pack(dict(value)))
        else:
            parts.append(pack.pack(value))
    size = sum(len(part) for part in parts)
    if size > max_bytes:
        raise OversizePayload(f"{msg.TAG}: encoded size {size} B exceeds {max_bytes} B")
    return b"".join(parts)


def _decode_array(name: str, value: object) -> np.ndarray[Any, Any]:
    if not (isinstance(value, list) and len(value) == 3):
        raise MalformedMessage(f"{name}: expected [dtype, shape, bytes]")
    dtype_name, shape, raw = value
    dtype = WIRE_DTYPES.get(dtype_name) if isinstance(dtype_name, str) else None
    if dtype is None:
        raise MalformedMessage(f"{name}: dtype {dtype_name!r} not in the allow-list")
    if not (
        isinstance(shape, list)
        and len(shape) <= _MAX_NDIM
        and all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
    ):
        raise MalformedMessage(f"{name}: shape must be a list of at most {_MAX_NDIM} non-negative ints")
    if not isinstance(raw, bytes):
        raise MalformedMessage(f"{name}: array data must be msgpack bin")
    if math.prod(shape) * dtype.itemsize != len(raw):
        raise MalformedMessage(f"{name}: {len(raw)} bytes do not hold shape {shape} of {dtype_name}")
    # frombuffer over immutable bytes yields a read-only array: zero-copy and safe to share.
    return np.frombuffer(raw, dtype=dtype).reshape(shape)


def _decode_scalar(name: str, spec: FieldSpec, value: object) -> object:
    if spec.kind == "float" and isinstance(value, int) and not isinstance(value, bool):
        return float(value)  # a client in another language may write an integral float as an int
    return value


def _decode_body(cls: type[Message], body: object) -> Message:
    if not isinstance(body, dict):
        raise MalformedMessage(f"{cls.TAG}: fields must be a map")
    specs = field_specs(cls)
    if body.keys() != specs.keys():
        missing, extra = specs.keys() - body.keys(), body.keys() - specs.keys()
        raise MalformedMessage(
            f"{cls.TAG}: missing fields {sorted(missing)}, unknown fields {sorted(map(repr, extra))}"
        )
    kwargs: dict[str, Any] = {
        name: _decode_array(name, value) if specs[name].kind == "array" else _decode_scalar(name, specs[name], value)
        for name, value in body.items()
    }
    return cls(**kwargs)


def decode(data: bytes | bytearray | memoryview, *, max_bytes: int = MAX_PAYLOAD_BYTES) -> Message:
    """Parse and validate one payload; raise only :class:`ProtocolError` subclasses, whatever ``data`` is."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise MalformedMessage(f"payload must be bytes-like, got {type(data).__name__}")
    size = data.nbytes if isinstance(data, memoryview) else len(data)
    if size > max_bytes:
        raise OversizePayload(f"payload of {size} B exceeds {max_bytes} B")
    try:
        envelope = msgpack.unpackb(data, raw=False, strict_map_key=True, max_bin_len=max_bytes, **_UNPACK_LIMITS)
    except Exception as exc:  # msgpack raises ValueError, TypeError and its own types for bad input
        raise MalformedMessage(f"not a valid msgpack document: {exc}") from exc
    if not (isinstance(envelope, list) and envelope):
        raise MalformedMessage("envelope must be a non-empty msgpack array")
    version = envelope[0]
    if not isinstance(version, int) or isinstance(version, bool):
        raise MalformedMessage("envelope[0] must be the schema version (int)")
    if version != SCHEMA_VERSION:
        raise SchemaVersionMismatch(f"schema version {version}, this build speaks {SCHEMA_VERSION}")
    if len(envelope) != 3:
        raise MalformedMessage(f"envelope must have 3 elements, got {len(envelope)}")
    tag, body = envelope[1], envelope[2]
    cls = MESSAGE_TYPES.get(tag) if isinstance(tag, str) else None
    if cls is None:
        raise MalformedMessage(f"unknown message type tag {tag!r}")
    try:
        return _decode_body(cls, body)
    except ProtocolError:
        raise
    except Exception as exc:
        # Defence in depth: the contract is ProtocolError only, so a validation bug must not leak out.
        log.exception("unexpected error decoding %s", tag)
        raise MalformedMessage(f"{tag}: {type(exc).__name__}: {exc}") from exc


def peek_sequence(
    data: bytes | bytearray | memoryview, *, max_bytes: int = MAX_PAYLOAD_BYTES
) -> tuple[str, int, int] | None:
    """(actor_id, incarnation, seq) of an ``experience`` or ``qinc`` payload that :func:`decode` refused, if its
    envelope and those three fields are readable; else None. Lets a receiver reject the message explicitly by its
    sequence number instead of leaving a hole the cumulative ack can never pass."""
    size = data.nbytes if isinstance(data, memoryview) else len(data)
    if size > max_bytes:
        return None
    try:
        envelope = msgpack.unpackb(data, raw=False, strict_map_key=True, max_bin_len=max_bytes, **_UNPACK_LIMITS)
    except Exception:  # not msgpack at all: nothing can be told about it
        return None
    if not (isinstance(envelope, list) and len(envelope) == 3 and envelope[1] in ("experience", "qinc")):
        return None
    body = envelope[2]
    if not isinstance(body, dict):
        return None
    actor_id, incarnation, seq = body.get("actor_id"), body.get("incarnation"), body.get("seq")
    try:
        check_id(actor_id, "actor_id")
    except ProtocolError:
        return None
    for value in (incarnation, seq):
        if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 2**64:
            return None
    return str(actor_id), int(incarnation), int(seq)  # type: ignore[arg-type]


def decode_as(data: bytes | bytearray | memoryview, cls: type[M], *, max_bytes: int = MAX_PAYLOAD_BYTES) -> M:
    """Like :func:`decode`, but raise :class:`UnexpectedMessageType` unless the message is a ``cls``."""
    msg = decode(data, max_bytes=max_bytes)
    if not isinstance(msg, cls):
        raise UnexpectedMessageType(f"expected {cls.TAG}, got {msg.TAG}")
    return msg
