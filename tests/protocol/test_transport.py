"""Key expressions, QoS, and both transports.

The zenoh tests run two sessions in this process on loopback (peer mode, multicast scouting off; one
listens on a free port, the others connect), as the deployment does across machines.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from protocol import (
    DEFAULT_KEYS,
    QOS,
    SCHEMA_VERSION,
    Ack,
    Channel,
    ExperienceBatch,
    IdentityMismatch,
    InMemoryBus,
    InMemoryTransport,
    InvalidValues,
    KeySpace,
    PolicyUpdate,
    Status,
    Transport,
    TransportClosed,
    UnexpectedMessageType,
    ZenohTransport,
    add_connection_args,
    config_from_args,
    encode,
    keys_from_args,
    message_equal,
    zenoh_config,
)
from protocol.zenoh_transport import SHM_POOL_BYTES, _reopen_after_s
from tests.protocol.conftest import golden_samples, sample_policy
from tools.system import free_port

GOLDEN = golden_samples()
K = DEFAULT_KEYS


def batch(seq: int, n: int = 256, d: int = 6) -> ExperienceBatch:
    rng = np.random.default_rng(seq)
    return ExperienceBatch(
        actor_id="actor-0",
        incarnation=42,
        seq=seq,
        policy_version=0,
        featurizer="collab6d",
        reward_function="eq2",
        action_set="compass",
        robot=rng.integers(0, 10, n).astype(np.int16),
        state=rng.random((n, d), np.float32),
        action=rng.integers(0, 8, n).astype(np.uint8),
        reward=rng.random(n, np.float32),
        next_state=rng.random((n, d), np.float32),
        done=rng.random(n) < 0.01,
    )


def wait_until(cond: Callable[[], bool], timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


# --- keys --------------------------------------------------------------------------------------------------


def test_key_layout() -> None:
    assert K.experience("actor-3") == "enncql/v2/experience/actor-3"
    assert K.experience() == "enncql/v2/experience/*"
    assert K.qinc("a") == "enncql/v2/qinc/a"
    assert K.ack("a") == "enncql/v2/ack/a"
    assert K.policy() == "enncql/v2/policy"
    assert K.policy_latest() == "enncql/v2/policy/latest"
    assert K.status("learner-0") == "enncql/v2/status/learner-0"
    assert K.alive("actor", "a") == "enncql/v2/alive/actor/a"
    assert K.alive() == "enncql/v2/alive/*/*"
    assert KeySpace("run-42/x").experience("a") == "run-42/x/enncql/v2/experience/a"
    with pytest.raises(InvalidValues):
        KeySpace("run//x")


@pytest.mark.parametrize("bad", ["", "a/b", "**", "a*", "$x", "a?", "a#", "@a", "x" * 65])
def test_keys_reject_bad_ids(bad: str) -> None:
    with pytest.raises(InvalidValues):
        K.experience(bad)
    if bad and "/" not in bad:  # a namespace may be empty (none) or several chunks
        with pytest.raises(InvalidValues):
            KeySpace(bad)
        with pytest.raises(InvalidValues):
            KeySpace(f"run/{bad}")


def test_alive_rejects_unknown_role() -> None:
    with pytest.raises(InvalidValues):
        K.alive("boss", "a")


def test_channel_and_message_type_of_keys() -> None:
    assert K.channel(K.experience("a")) is Channel.EXPERIENCE
    assert K.channel(K.policy_latest()) is Channel.POLICY
    assert K.message_type(K.policy()) is PolicyUpdate
    assert K.message_type(K.ack("a")) is Ack
    for bad in ["enncql/v3/experience/a", "enncql/v2/experience/a/b", "enncql/v2/policy/old", "other/thing"]:
        with pytest.raises(InvalidValues):
            K.channel(bad)
    with pytest.raises(InvalidValues):
        K.message_type(K.alive("actor", "a"))
    with pytest.raises(InvalidValues):
        KeySpace("ns").channel(K.experience("a"))


def test_qos_table() -> None:
    block, drop = zenoh.CongestionControl.BLOCK, zenoh.CongestionControl.DROP
    for channel in (Channel.EXPERIENCE, Channel.QINC, Channel.ACK, Channel.POLICY):
        assert QOS[channel].reliable and QOS[channel].congestion_control == block
    assert QOS[Channel.STATUS].congestion_control == drop and not QOS[Channel.STATUS].reliable
    assert K.qos(K.experience("a")).reliability == zenoh.Reliability.RELIABLE


def test_connection_args() -> None:
    parser = argparse.ArgumentParser()
    add_connection_args(parser)
    args = parser.parse_args(["--connect", "tcp/127.0.0.1:7447", "--connect", "tcp/10.0.0.2:7447", "--mode", "client"])
    assert args.connect == ["tcp/127.0.0.1:7447", "tcp/10.0.0.2:7447"] and args.mode == "client"
    conf = config_from_args(args)
    assert conf.get_json("connect/endpoints") == '["tcp/127.0.0.1:7447","tcp/10.0.0.2:7447"]'
    assert conf.get_json("connect/timeout_ms") == "-1"
    assert conf.get_json("scouting/multicast/enabled") == "false"
    assert keys_from_args(parser.parse_args(["--namespace", "run-1"])).root == "run-1/enncql/v2"
    with pytest.raises(ValueError):
        zenoh_config(mode="satellite")


def test_zenoh_config_file_is_overridden_only_by_given_flags(tmp_path: Any) -> None:
    path = tmp_path / "z.json5"
    path.write_text('{ scouting: { multicast: { enabled: true } }, listen: { endpoints: ["tcp/127.0.0.1:0"] } }')
    conf = zenoh_config(config_file=str(path))
    assert conf.get_json("scouting/multicast/enabled") == "true"
    assert conf.get_json("listen/endpoints") == '["tcp/127.0.0.1:0"]'
    assert (
        zenoh_config(config_file=str(path), multicast_scouting=False).get_json("scouting/multicast/enabled") == "false"
    )


def test_the_shared_memory_pool_is_small_unless_a_file_sets_it(tmp_path: Any) -> None:
    pool = "transport/shared_memory/transport_optimization/pool_size"
    assert zenoh.Config().get_json(pool) == str(16 * 2**20)  # Zenoh's own default, which every actor mapped twice
    assert zenoh_config(connect=["tcp/127.0.0.1:7447"]).get_json(pool) == str(SHM_POOL_BYTES) == str(4 * 2**20)
    path = tmp_path / "z.json5"
    path.write_text("{ transport: { shared_memory: { transport_optimization: { pool_size: 8388608 } } } }")
    assert zenoh_config(config_file=str(path)).get_json(pool) == "8388608"


# --- in-memory transport -----------------------------------------------------------------------------------


def test_memory_pub_sub_with_wildcards() -> None:
    bus = InMemoryBus()
    with InMemoryTransport(bus) as learner, InMemoryTransport(bus) as actor:
        one: list[ExperienceBatch] = []
        everything: list[Any] = []
        learner.subscribe(K.experience(), ExperienceBatch, one.append)
        assert actor.has_subscribers(K.experience("actor-0"))
        assert not actor.has_subscribers(K.qinc("actor-0"))
        learner.subscribe("enncql/v2/**", ExperienceBatch, everything.append)
        learner.subscribe(K.experience("actor-1"), ExperienceBatch, lambda m: pytest.fail("wrong actor"))
        sent = batch(0)
        actor.publish(K.experience("actor-0"), sent)
        assert len(one) == len(everything) == 1
        assert message_equal(one[0], sent) and one[0] is not sent
        assert not one[0].state.flags.writeable
        assert actor.stats.published == 1 and learner.stats.delivered == 2


def test_memory_rejections_are_counted_and_not_raised() -> None:
    bus = InMemoryBus()
    with InMemoryTransport(bus) as learner, InMemoryTransport(bus) as actor:
        got: list[ExperienceBatch] = []
        learner.subscribe(K.experience(), ExperienceBatch, got.append)
        key = K.experience("actor-0")
        actor.inject_raw(key, b"\x93garbage")
        actor.inject_raw(key, encode(GOLDEN["status"]))
        actor.inject_raw(key, msgpack.packb([SCHEMA_VERSION + 1, "experience", {}]))
        actor.publish(key, batch(1))
        assert [m.seq for m in got] == [1]
        assert learner.stats.rejected == {"MalformedMessage": 1, "UnexpectedMessageType": 1, "SchemaVersionMismatch": 1}
        assert learner.stats.rejected_total == 3
        with pytest.raises(UnexpectedMessageType):
            actor.publish(key, GOLDEN["status"])
        with pytest.raises(InvalidValues):
            actor.publish("somewhere/else", batch(2))


def test_memory_handler_errors_are_contained() -> None:
    with InMemoryTransport() as t:

        def boom(_: Status) -> None:
            raise RuntimeError("handler bug")

        t.subscribe(K.status(), Status, boom)
        t.publish(K.status("learner-0"), GOLDEN["status"])
        assert t.stats.handler_errors == 1


def test_memory_queryable_answers_late_joiner() -> None:
    bus = InMemoryBus()
    current: list[PolicyUpdate] = []
    with InMemoryTransport(bus) as learner:
        learner.declare_queryable(K.policy_latest(), lambda: current[-1] if current else None)
        with InMemoryTransport(bus) as early:
            assert early.get(K.policy_latest(), PolicyUpdate) == []
        current.append(sample_policy(5))
        with InMemoryTransport(bus) as late:
            replies = late.get(K.policy_latest(), PolicyUpdate)
            assert [r.version for r in replies] == [5]
            assert late.get("enncql/v2/policy/*", PolicyUpdate)[0].version == 5


def test_memory_liveliness() -> None:
    bus = InMemoryBus()
    events: list[tuple[str, str]] = []
    with InMemoryTransport(bus) as learner:
        with InMemoryTransport(bus) as actor:
            early = actor.liveliness_token(K.alive("actor", "a0"))
            learner.liveliness_subscribe(
                K.alive("actor"), lambda k: events.append(("join", k)), lambda k: events.append(("leave", k))
            )
            assert events == [("join", K.alive("actor", "a0"))]
            actor.liveliness_token(K.alive("actor", "a1"))
            actor.liveliness_token(K.alive("learner", "x"))  # not matched by the subscription
            early.close()
            early.close()
        assert events == [
            ("join", K.alive("actor", "a0")),
            ("join", K.alive("actor", "a1")),
            ("leave", K.alive("actor", "a0")),
            ("leave", K.alive("actor", "a1")),  # the transport closed
        ]
    with pytest.raises(TransportClosed):
        actor.publish(K.experience("a0"), batch(0))


def test_memory_handlers_may_publish() -> None:
    bus = InMemoryBus()
    with InMemoryTransport(bus) as learner, InMemoryTransport(bus) as actor:
        acks: list[Ack] = []

        def store(msg: ExperienceBatch) -> None:
            learner.publish(K.ack(msg.actor_id), Ack(actor_id=msg.actor_id, incarnation=msg.incarnation, seq=msg.seq))

        learner.subscribe(K.experience(), ExperienceBatch, store)
        actor.subscribe(K.ack("actor-0"), Ack, acks.append)
        for seq in range(3):
            actor.publish(K.experience("actor-0"), batch(seq))
        assert [a.seq for a in acks] == [0, 1, 2]


# --- zenoh transport ---------------------------------------------------------------------------------------


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


def _connected(t: ZenohTransport, to: ZenohTransport) -> ZenohTransport:
    peer = str(to.session.zid())
    assert wait_until(lambda: peer in map(str, t.session.info.peers_zid())), "zenoh sessions did not connect"
    return t


@pytest.fixture
def pair(endpoint: str) -> Iterator[tuple[ZenohTransport, ZenohTransport]]:
    """(listener, connector): two connected sessions in this process."""
    with (
        ZenohTransport.open(zenoh_config(listen=[endpoint])) as a,
        ZenohTransport.open(zenoh_config(connect=[endpoint])) as b,
    ):
        yield a, _connected(b, a)


def _worker_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("zenoh-")]


def test_zenoh_block_delivers_everything_in_order(pair: tuple[ZenohTransport, ZenohTransport]) -> None:
    learner, actor = pair
    got: list[int] = []
    tuples = [0]

    def slow_store(msg: ExperienceBatch) -> None:
        got.append(msg.seq)
        tuples[0] += msg.n_tuples
        if msg.seq % 50 == 0:
            time.sleep(0.05)  # a consumer hiccup: the FifoChannel fills and the BLOCK publisher must wait

    key = K.experience("actor-0")
    assert not actor.has_subscribers(key)
    learner.subscribe(K.experience(), ExperienceBatch, slow_store)
    assert wait_until(lambda: actor.has_subscribers(key))
    n = 300
    for seq in range(n):
        actor.publish(key, batch(seq))
    assert wait_until(lambda: len(got) == n, timeout=20)
    assert got == list(range(n))
    assert tuples[0] == n * 256
    assert actor.stats.published == learner.stats.delivered == n
    assert learner.stats.rejected_total == 0


def test_zenoh_malformed_payload_is_counted_and_next_message_arrives(
    pair: tuple[ZenohTransport, ZenohTransport],
) -> None:
    learner, actor = pair
    got: list[ExperienceBatch] = []
    learner.subscribe(K.experience(), ExperienceBatch, got.append)
    key = K.experience("actor-0")
    assert wait_until(lambda: actor.has_subscribers(key))
    actor.session.put(key, b"\xde\xad\xbe\xef", congestion_control=zenoh.CongestionControl.BLOCK)
    actor.session.put(key, encode(GOLDEN["ack"]), congestion_control=zenoh.CongestionControl.BLOCK)
    actor.publish(key, batch(9))
    assert wait_until(lambda: len(got) == 1)
    assert got[0].seq == 9
    assert learner.stats.rejected == {"MalformedMessage": 1, "UnexpectedMessageType": 1}


def get_soon(t: ZenohTransport, timeout: float = 5.0) -> list[PolicyUpdate]:
    """Right after connecting, the learner's queryable may not have been announced yet: retry a while."""
    deadline = time.monotonic() + timeout
    while True:
        replies = t.get(K.policy_latest(), PolicyUpdate, timeout=1.0)
        if replies or time.monotonic() > deadline:
            return replies
        time.sleep(0.05)


def test_zenoh_queryable_answers_late_get(endpoint: str) -> None:
    current: list[PolicyUpdate] = []
    with ZenohTransport.open(zenoh_config(listen=[endpoint])) as learner:
        learner.declare_queryable(K.policy_latest(), lambda: current[-1] if current else None)
        current.append(sample_policy(7))
        with ZenohTransport.open(zenoh_config(connect=[endpoint])) as late:
            _connected(late, learner)
            replies = get_soon(late)
            assert len(replies) == 1 and message_equal(replies[0], current[-1])
        current.append(sample_policy(8))
        with ZenohTransport.open(zenoh_config(connect=[endpoint])) as later:
            _connected(later, learner)
            assert [r.version for r in get_soon(later)] == [8]


def test_zenoh_liveliness_join_leave_and_session_close(endpoint: str) -> None:
    events: list[tuple[str, str]] = []
    with ZenohTransport.open(zenoh_config(listen=[endpoint])) as learner:
        learner.liveliness_subscribe(
            K.alive("actor"), lambda k: events.append(("join", k)), lambda k: events.append(("leave", k))
        )
        a0, a1 = K.alive("actor", "a0"), K.alive("actor", "a1")
        with ZenohTransport.open(zenoh_config(connect=[endpoint])) as actor:
            _connected(actor, learner)
            token = actor.liveliness_token(a0)
            assert wait_until(lambda: ("join", a0) in events)
            token.close()
            assert wait_until(lambda: ("leave", a0) in events)
            actor.liveliness_token(a1)
            assert wait_until(lambda: ("join", a1) in events)
        assert wait_until(lambda: ("leave", a1) in events)  # the actor's session closed
    assert events == [("join", a0), ("leave", a0), ("join", a1), ("leave", a1)]


def test_zenoh_liveliness_history_reports_present_tokens(pair: tuple[ZenohTransport, ZenohTransport]) -> None:
    learner, actor = pair
    a0 = K.alive("actor", "a0")
    seen: list[str] = []
    learner.liveliness_subscribe(K.alive("actor"), seen.append, seen.append, history=False)
    actor.liveliness_token(a0)
    assert wait_until(lambda: seen == [a0])
    joined: list[str] = []
    learner.liveliness_subscribe(K.alive("actor"), joined.append, joined.append, history=True)
    assert wait_until(lambda: joined == [a0])


def test_zenoh_close_joins_workers_and_rejects_use(endpoint: str) -> None:
    with ZenohTransport.open(zenoh_config(listen=[endpoint])) as t:
        t.subscribe(K.experience(), ExperienceBatch, lambda m: None)
        t.declare_queryable(K.policy_latest(), lambda: None)
        t.liveliness_subscribe(K.alive(), lambda k: None, lambda k: None)
        assert len(_worker_threads()) == 3
        t.close()
        assert _worker_threads() == []
        assert t.session.is_closed()
        with pytest.raises(TransportClosed):
            t.publish(K.experience("actor-0"), batch(0))
        with pytest.raises(TransportClosed):
            t.subscribe(K.experience(), ExperienceBatch, lambda m: None)


def test_both_transports_satisfy_the_interface(pair: tuple[ZenohTransport, ZenohTransport]) -> None:
    transports: list[Transport] = [pair[0], InMemoryTransport()]
    assert all(t.keys == K for t in transports)


def test_a_stream_is_bound_to_its_keys_identity() -> None:
    bus = InMemoryBus()
    got: list[ExperienceBatch] = []
    with InMemoryTransport(bus) as liar, InMemoryTransport(bus) as learner:
        learner.subscribe(learner.keys.experience(), ExperienceBatch, got.append)
        with pytest.raises(IdentityMismatch):
            liar.publish(liar.keys.experience("mallory"), batch(0))  # refused before the wire
        liar.inject_raw(liar.keys.experience("mallory"), encode(batch(0)))  # a peer that skips the check
        liar.publish(liar.keys.experience("actor-0"), batch(1))
    assert [m.seq for m in got] == [1]
    assert learner.stats.rejected == {"IdentityMismatch": 1}


def test_a_client_without_a_router_reopens_its_session_and_declares_everything_anew(endpoint: str) -> None:
    # The watchdog's path, end to end: a client session that sees no router for reopen_after_s is closed and opened
    # anew, and its subscriptions, liveliness token, queryable and publishers work on the new one. (The broken
    # session that calls for it, connected in name only after a partition, is the chaos suite's network faults.)
    def router() -> zenoh.Session:
        return zenoh.open(zenoh_config(listen=[endpoint], mode="router"))

    client = zenoh_config(connect=[endpoint], mode="client")
    got: list[int] = []
    joins: list[str] = []
    first = router()
    with (
        ZenohTransport.open(client, reopen_after_s=1.0) as actor,
        ZenohTransport.open(client, reopen_after_s=3600.0) as learner,
    ):
        learner.subscribe(K.experience(), ExperienceBatch, lambda msg: got.append(msg.seq))
        learner.liveliness_subscribe(K.alive("actor"), joins.append, lambda _key: None)
        actor.liveliness_token(K.alive("actor", "actor-0"))
        actor.declare_queryable(K.experience("actor-0"), lambda: batch(7))
        key = K.experience("actor-0")
        assert wait_until(lambda: actor.has_subscribers(key))
        actor.publish(key, batch(0))
        assert wait_until(lambda: got == [0]) and wait_until(lambda: len(joins) == 1)
        before = actor.session
        first.close()
        assert wait_until(lambda: before.is_closed(), timeout=15.0)  # reopening: it waits for a router
        assert actor.has_subscribers(key) is False
        actor.publish(key, batch(1))  # dropped, as zenoh drops what no router takes
        with router():
            assert wait_until(lambda: actor.reopened == 1 and actor.has_subscribers(key), timeout=15.0)
            assert actor.session is not before and not actor.session.is_closed()
            assert learner.reopened == 0  # its own session reconnected by itself within the hour
            actor.publish(key, batch(2))
            assert wait_until(lambda: got == [0, 2])
            assert wait_until(lambda: len(joins) == 2)  # the token declared again on the new session
            assert [m.seq for m in learner.get(key, ExperienceBatch)] == [7]  # the queryable too
            assert actor.stats.published == 2


def test_only_a_client_with_a_router_to_connect_to_is_watched(endpoint: str) -> None:
    with ZenohTransport.open(zenoh_config(listen=[endpoint]), reopen_after_s=1.0) as peer:
        assert peer._watchdog is None  # a peer lists no router: it would reopen for nothing
    with zenoh.open(zenoh_config(listen=[endpoint], mode="router")):
        conf = zenoh_config(connect=[endpoint], mode="client")
        conf.insert_json5("transport/link/tx/lease", "4000")
        assert _reopen_after_s(conf) == 8.0
        with ZenohTransport.open(conf) as client:
            assert client._watchdog is not None and client._watchdog.is_alive()
        assert not client._watchdog.is_alive()
