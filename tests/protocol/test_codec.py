"""Messages and codec: round trips, golden bytes, validation and fuzzing.

The golden files pin the wire format; after an intended format change (which also bumps SCHEMA_VERSION)
rewrite them with ``python -m tests.protocol.test_codec --regenerate-golden``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol import (
    MAX_PAYLOAD_BYTES,
    N_ACTIONS,
    SCHEMA_VERSION,
    Ack,
    ExperienceBatch,
    InvalidValues,
    MalformedMessage,
    Message,
    OversizePayload,
    ProtocolError,
    SchemaVersionMismatch,
    Status,
    UnexpectedMessageType,
    check_id,
    decode,
    decode_as,
    encode,
    message_equal,
)
from tests.protocol.conftest import golden_samples, messages, sample_batch

GOLDEN_DIR = Path(__file__).parent / "golden"
GOLDEN = golden_samples()
BATCH = decode_as(encode(sample_batch()), ExperienceBatch)


def envelope(tag: str, body: Any, version: int = SCHEMA_VERSION) -> bytes:
    return msgpack.packb([version, tag, body], use_bin_type=True)


def golden_body(name: str) -> dict[str, Any]:
    body: dict[str, Any] = msgpack.unpackb(encode(GOLDEN[name]), raw=False)[2]
    return body


def replace(msg: Message, **changes: Any) -> Message:
    """Bypass validation on construction to build an invalid message (arrays mutated after the fact)."""
    out = dataclasses.replace(msg)
    for name, value in changes.items():
        object.__setattr__(out, name, value)
    return out


# --- round trips -------------------------------------------------------------------------------------------


@given(messages)
@settings(max_examples=150, suppress_health_check=[HealthCheck.too_slow])
def test_round_trip(msg: Message) -> None:
    data = encode(msg)
    back = decode(data)
    assert message_equal(back, msg)
    assert encode(back) == data
    assert message_equal(decode(memoryview(data)), msg)


@pytest.mark.parametrize("n", [0, 1, 31, 32, 2047, 2048, 16384])
def test_encode_writes_the_bytes_msgpack_itself_would(n: int) -> None:
    # Sizes on both sides of the bin 8 / 16 / 32 headers (255 and 65535 bytes of state at d = 2 and 6).
    for dim in (2, 6):
        rng = np.random.default_rng(n)
        msg = ExperienceBatch(
            actor_id="actor-0",
            incarnation=2**64 - 1,
            seq=n,
            policy_version=3,
            featurizer="collab6d",
            reward_function="eq2",
            action_set="compass",
            robot=rng.integers(0, 10, n).astype(np.int16),
            state=rng.random((n, dim), dtype=np.float32),
            action=rng.integers(0, N_ACTIONS, n).astype(np.uint8),
            reward=rng.random(n, dtype=np.float32),
            next_state=rng.random((n, dim), dtype=np.float32),
            done=rng.random(n) < 0.5,
        )
        body = {
            name: [value.dtype.name, list(value.shape), value.tobytes()] if isinstance(value, np.ndarray) else value
            for name, value in ((f.name, getattr(msg, f.name)) for f in dataclasses.fields(msg))
        }
        assert encode(msg) == msgpack.packb([SCHEMA_VERSION, "experience", body], use_bin_type=True)


def test_decode_as_checks_the_type() -> None:
    data = encode(GOLDEN["ack"])
    assert decode_as(data, Ack).seq == 8
    with pytest.raises(UnexpectedMessageType):
        decode_as(data, ExperienceBatch)


def test_decoded_arrays_are_read_only() -> None:
    assert not BATCH.state.flags.writeable
    with pytest.raises(ValueError):
        BATCH.state[0, 0] = 1.0


def test_non_contiguous_and_empty_arrays_encode() -> None:
    state = np.arange(24, dtype=np.float32).reshape(6, 4)[:, ::2]
    batch = dataclasses.replace(
        BATCH,
        robot=np.zeros(6, np.int16),
        state=state,
        action=np.zeros(6, np.uint8),
        reward=np.zeros(6, np.float32),
        next_state=np.asfortranarray(state),
        done=np.zeros(6, bool),
    )
    assert message_equal(decode(encode(batch)), batch)
    empty = dataclasses.replace(
        BATCH,
        robot=np.zeros(0, np.int16),
        state=np.zeros((0, 6), np.float32),
        action=np.zeros(0, np.uint8),
        reward=np.zeros(0, np.float32),
        next_state=np.zeros((0, 6), np.float32),
        done=np.zeros(0, bool),
    )
    assert decode_as(encode(empty), ExperienceBatch).n_tuples == 0


def test_status_counters_are_read_only_floats() -> None:
    status = Status(sender="a", role="actor", wall_time=1.0, counters={"n": 3})
    assert status.counters == {"n": 3.0} and isinstance(status.counters["n"], float)
    with pytest.raises(TypeError):
        status.counters["n"] = 4.0  # type: ignore[index]


# --- golden bytes ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_encoding_is_pinned(name: str) -> None:
    assert encode(GOLDEN[name]) == (GOLDEN_DIR / f"{name}.msgpack").read_bytes()


@pytest.mark.parametrize("name", sorted(GOLDEN))
def test_golden_bytes_decode(name: str) -> None:
    assert message_equal(decode((GOLDEN_DIR / f"{name}.msgpack").read_bytes()), GOLDEN[name])


def test_golden_layout_is_the_documented_envelope() -> None:
    version, tag, body = msgpack.unpackb((GOLDEN_DIR / "experience.msgpack").read_bytes(), raw=False)
    assert (version, tag) == (2, "experience")
    assert list(body) == [
        "actor_id",
        "incarnation",
        "seq",
        "policy_version",
        "featurizer",
        "reward_function",
        "action_set",
        "robot",
        "state",
        "action",
        "reward",
        "next_state",
        "done",
    ]
    assert body["state"] == ["float32", [2, 2], np.array([[0.5, -1.0], [2.0, 0.25]], "<f4").tobytes()]


# --- validation --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "changes", "error"),
    [
        ("experience", {"reward": np.array([np.nan, 0.0], np.float32)}, InvalidValues),
        ("experience", {"state": np.array([[np.inf, 0.0], [0.0, 0.0]], np.float32)}, InvalidValues),
        ("experience", {"state": np.zeros((2, 2), np.float64)}, MalformedMessage),
        ("experience", {"next_state": np.zeros((2, 3), np.float32)}, MalformedMessage),
        ("experience", {"reward": np.zeros(3, np.float32)}, MalformedMessage),
        ("experience", {"reward": np.zeros((2, 1), np.float32)}, MalformedMessage),
        ("experience", {"action": np.array([0, N_ACTIONS], np.uint8)}, InvalidValues),
        ("experience", {"robot": np.array([0, -1], np.int16)}, InvalidValues),
        ("experience", {"robot": [0, 1]}, MalformedMessage),
        ("experience", {"seq": -1}, InvalidValues),
        ("experience", {"seq": 2**64}, InvalidValues),
        ("experience", {"seq": True}, MalformedMessage),
        ("experience", {"incarnation": 1.0}, MalformedMessage),
        ("experience", {"actor_id": "a/b"}, InvalidValues),
        (
            "experience",
            {"state": np.zeros((2, 0), np.float32), "next_state": np.zeros((2, 0), np.float32)},
            MalformedMessage,
        ),
        ("qinc", {"offsets": np.array([0, 2, 1, 3, 4, 5, 6, 7, 8], np.int64)}, InvalidValues),
        ("qinc", {"offsets": np.arange(N_ACTIONS + 1, dtype=np.int64) + 1}, InvalidValues),
        ("qinc", {"offsets": np.arange(N_ACTIONS, dtype=np.int64)}, MalformedMessage),
        ("qinc", {"visits": np.zeros(N_ACTIONS, np.int32)}, MalformedMessage),
        ("qinc", {"robot": 2**15}, InvalidValues),
        ("policy", {"version": 0}, InvalidValues),
        # The wire checks a formulation's names for their syntax only: which names exist is the processes' business.
        ("experience", {"featurizer": "a b"}, InvalidValues),
        ("experience", {"reward_function": ""}, InvalidValues),
        ("experience", {"action_set": 8}, MalformedMessage),
        ("policy", {"featurizer": "shared/8d"}, InvalidValues),
        ("policy", {"reward_function": "*"}, InvalidValues),
        ("policy", {"action_set": None}, MalformedMessage),
        ("policy", {"scale": np.ones(3, np.float32)}, MalformedMessage),
        ("policy", {"scenario": ""}, InvalidValues),
        ("policy", {"action_steps": 0}, InvalidValues),
        ("policy", {"robots": np.array([5, 5], np.int16)}, InvalidValues),
        ("policy", {"q_tables": np.ones((2, N_ACTIONS + 1), np.float32)}, MalformedMessage),
        ("policy", {"labels": np.full(N_ACTIONS, np.nan, np.float32)}, InvalidValues),
        ("status", {"role": "boss"}, InvalidValues),
        ("status", {"wall_time": math.nan}, InvalidValues),
        ("status", {"counters": {"x": math.inf}}, InvalidValues),
        ("status", {"counters": {"": 1.0}}, InvalidValues),
        ("status", {"counters": {"x" * 65: 1.0}}, InvalidValues),
        ("status", {"counters": {str(i): 1.0 for i in range(65)}}, InvalidValues),
        ("status", {"counters": {"x": True}}, MalformedMessage),
        ("status", {"counters": {"x": 10**400}}, InvalidValues),
        ("status", {"counters": [("x", 1.0)]}, MalformedMessage),
        ("view", {"counters": {"learner/coverage": 1.0}}, InvalidValues),  # only the actor's own series
        ("view", {"counters": {"coverage": math.nan}}, InvalidValues),
        ("view", {"robot_pos": np.full((2, 3, 2), np.inf, np.float32)}, InvalidValues),
        ("view", {"robot_pos": np.zeros((1, 3, 2), np.float32)}, MalformedMessage),  # 1 frame of robots, 2 of targets
        ("view", {"target_pos": np.zeros((2, 2, 3), np.float32)}, MalformedMessage),
        ("view", {"frame_time": np.array([-1.0, 0.0])}, InvalidValues),
        ("view", {"train_time": -0.5}, InvalidValues),
        ("view", {"sensing_range": 0.0}, InvalidValues),
        ("view", {"frame_step": np.array([1, 2], np.int64)}, MalformedMessage),
        (
            "view",
            {
                "frame_step": np.zeros(1001, np.uint64),
                "frame_time": np.zeros(1001),
                "robot_pos": np.zeros((1001, 1, 2), np.float32),
                "target_pos": np.zeros((1001, 1, 2), np.float32),
            },
            InvalidValues,
        ),
        ("view", {"robot_pos": np.zeros((2, 257, 2), np.float32)}, InvalidValues),
    ],
)
def test_validation_rejects(name: str, changes: dict[str, Any], error: type[ProtocolError]) -> None:
    with pytest.raises(error):
        dataclasses.replace(GOLDEN[name], **changes)
    with pytest.raises(error):
        encode(replace(GOLDEN[name], **changes))


@pytest.mark.parametrize("good", ["a", "actor-0", "host.local_1-2", "_x", "A" * 64])
def test_valid_ids(good: str) -> None:
    assert check_id(good) == good


@pytest.mark.parametrize(
    "bad", ["", "a/b", "*", "**", "a*", "$x", "a?b", "a#b", "@a", "-a", ".a", "a b", "é", "A" * 65]
)
def test_invalid_ids(bad: str) -> None:
    with pytest.raises(InvalidValues):
        check_id(bad)


def test_mutating_an_array_after_construction_is_caught_by_encode() -> None:
    batch = dataclasses.replace(BATCH, reward=np.zeros(2, np.float32))
    batch.reward[0] = np.nan
    with pytest.raises(InvalidValues):
        encode(batch)


# --- decoding hostile input --------------------------------------------------------------------------------


def test_schema_version_mismatch() -> None:
    with pytest.raises(SchemaVersionMismatch):
        decode(envelope("ack", golden_body("ack"), version=SCHEMA_VERSION + 1))
    with pytest.raises(SchemaVersionMismatch):
        decode(msgpack.packb([SCHEMA_VERSION + 1, "some", "future", "layout"]))


def test_oversize() -> None:
    with pytest.raises(OversizePayload):
        decode(bytes(MAX_PAYLOAD_BYTES + 1))
    data = encode(GOLDEN["policy"])
    with pytest.raises(OversizePayload):
        decode(data, max_bytes=len(data) - 1)
    with pytest.raises(OversizePayload):
        encode(GOLDEN["policy"], max_bytes=len(data) - 1)


def _with_array(name: str, field: str, value: list[Any]) -> bytes:
    body = golden_body(name)
    body[field] = value
    return envelope(name, body)


@pytest.mark.parametrize(
    ("data", "error"),
    [
        (b"", MalformedMessage),
        (b"\xc1", MalformedMessage),
        (msgpack.packb({"v": 1}), MalformedMessage),
        (msgpack.packb([]), MalformedMessage),
        (msgpack.packb(["1", "ack", {}]), MalformedMessage),
        (msgpack.packb([True, "ack", {}]), MalformedMessage),
        (msgpack.packb([SCHEMA_VERSION, "ack"]), MalformedMessage),
        (msgpack.packb([SCHEMA_VERSION, "nope", {}]), MalformedMessage),
        (msgpack.packb([SCHEMA_VERSION, "ack", []]), MalformedMessage),
        (envelope("ack", {"actor_id": "a", "incarnation": 1}), MalformedMessage),
        (envelope("ack", {"actor_id": "a", "incarnation": 1, "seq": 2, "extra": 0}), MalformedMessage),
        (envelope("ack", {"actor_id": b"a", "incarnation": 1, "seq": 2}), MalformedMessage),
        (envelope("ack", {"actor_id": "a", "incarnation": -1, "seq": 2}), InvalidValues),
        (
            msgpack.packb(
                [SCHEMA_VERSION, "ack", {"actor_id": "a", "incarnation": 1, "seq": msgpack.ExtType(1, b"x")}]
            ),
            MalformedMessage,
        ),
        (msgpack.packb([SCHEMA_VERSION, "ack", {1: "a"}]), MalformedMessage),
        (msgpack.packb([SCHEMA_VERSION, "ack", {"actor_id": "x" * 300, "incarnation": 1, "seq": 2}]), MalformedMessage),
        (_with_array("experience", "reward", ["float64", [2], bytes(16)]), MalformedMessage),
        (_with_array("experience", "reward", ["object", [2], bytes(16)]), MalformedMessage),
        (_with_array("experience", "reward", ["<f4", [2], bytes(8)]), MalformedMessage),
        (_with_array("experience", "reward", ["float32", [3], bytes(8)]), MalformedMessage),
        (_with_array("experience", "reward", ["float32", [-2], bytes(8)]), MalformedMessage),
        (_with_array("experience", "reward", ["float32", [2], "abcdefgh"]), MalformedMessage),
        (_with_array("experience", "reward", ["float32", [2**62, 2**62], bytes(8)]), MalformedMessage),
        (_with_array("experience", "reward", ["float32", [2], np.array([np.nan, 1], "<f4").tobytes()]), InvalidValues),
        (_with_array("experience", "done", ["bool", [2], b"\x00\x02"]), InvalidValues),
        (_with_array("experience", "reward", ["float32", [2]]), MalformedMessage),
    ],
)
def test_decode_rejects(data: bytes, error: type[ProtocolError]) -> None:
    with pytest.raises(error):
        decode(data)


def test_decode_rejects_non_bytes() -> None:
    with pytest.raises(MalformedMessage):
        decode("not bytes")  # type: ignore[arg-type]


def test_every_truncation_is_rejected() -> None:
    for name in GOLDEN:
        data = encode(GOLDEN[name])
        for end in range(len(data)):
            with pytest.raises(ProtocolError):
                decode(data[:end])


def _decode_or_reject(data: bytes) -> None:
    """The decoder's whole contract: a valid message, or a ProtocolError; never any other exception."""
    try:
        msg = decode(data)
    except ProtocolError:
        return
    assert message_equal(decode(encode(msg)), msg)


@given(st.binary(max_size=1024))
@settings(max_examples=300)
def test_fuzz_arbitrary_bytes(data: bytes) -> None:
    _decode_or_reject(data)


@given(st.sampled_from(sorted(GOLDEN)), st.data())
@settings(max_examples=400)
def test_fuzz_mutated_payloads(name: str, draw: st.DataObject) -> None:
    data = bytearray(encode(GOLDEN[name]))
    for _ in range(draw.draw(st.integers(1, 4))):
        pos = draw.draw(st.integers(0, len(data) - 1))
        op = draw.draw(st.sampled_from(["flip", "set", "insert", "delete"]))
        if op == "flip":
            data[pos] ^= 1 << draw.draw(st.integers(0, 7))
        elif op == "set":
            data[pos] = draw.draw(st.integers(0, 255))
        elif op == "insert":
            data[pos:pos] = draw.draw(st.binary(min_size=1, max_size=8))
        elif len(data) > 1:
            del data[pos : pos + draw.draw(st.integers(1, 8))]
    _decode_or_reject(bytes(data))


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text(max_size=20)
    | st.binary(max_size=64),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=12,
)


@given(st.sampled_from(sorted(GOLDEN)), st.data(), msgpack_values)
@settings(max_examples=400)
def test_fuzz_field_values(name: str, draw: st.DataObject, value: Any) -> None:
    body = golden_body(name)
    body[draw.draw(st.sampled_from(sorted(body)))] = value
    _decode_or_reject(envelope(name, body))


@given(st.sampled_from(sorted(GOLDEN)), st.data())
@settings(max_examples=200)
def test_fuzz_array_headers(name: str, draw: st.DataObject) -> None:
    body = golden_body(name)
    arrays = [k for k, v in body.items() if isinstance(v, list)]
    if not arrays:
        return
    field = draw.draw(st.sampled_from(arrays))
    dtype, shape, raw = body[field]
    body[field] = [
        draw.draw(st.sampled_from([dtype, "bool", "uint8", "int16", "uint32", "int64", "float32", "float64"])),
        draw.draw(st.lists(st.integers(0, 20), max_size=3) | st.just(shape)),
        draw.draw(st.binary(max_size=128) | st.just(raw)),
    ]
    _decode_or_reject(envelope(name, body))


def _regenerate_golden() -> None:
    GOLDEN_DIR.mkdir(exist_ok=True)
    for name, msg in GOLDEN.items():
        (GOLDEN_DIR / f"{name}.msgpack").write_bytes(encode(msg))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--regenerate-golden", action="store_true", help="rewrite tests/protocol/golden/*.msgpack")
    if parser.parse_args().regenerate_golden:
        _regenerate_golden()
