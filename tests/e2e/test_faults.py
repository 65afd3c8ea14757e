"""Faults at the worst moment, from outside: the learner SIGKILLed just after a checkpoint landed (the moment with
the most unsaved state), then resumed; a peer that sends under another actor's identity.

Asserted: tuples exactly once; every acknowledged increment's visits are in the final tables; policy versions
strictly increase across the restart; the run's clock goes on from the checkpoint; nothing a lying peer sends is
stored.
"""

from __future__ import annotations

import re
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from algorithm.policy_file import load_policy
from learner.checkpoint import VersionMark
from protocol import ExperienceBatch, PolicyUpdate, ZenohTransport, zenoh_config
from protocol.keys import KeySpace
from tests.e2e.test_cluster import Cluster, checkpoint_version, cluster, finish, wait_for

pytestmark = pytest.mark.slow
__all__ = ["cluster"]  # the fixture, imported for this module's tests


class PolicyWatch:
    """Every policy version seen on the wire, in arrival order (a session of the test's own)."""

    def __init__(self, c: Cluster) -> None:
        self.versions: list[int] = []
        self._lock = threading.Lock()
        conf = zenoh_config(connect=[c.endpoint], mode="peer", multicast_scouting=False)
        self.transport = ZenohTransport.open(conf, KeySpace(c.namespace))
        self.transport.subscribe(self.transport.keys.policy(), PolicyUpdate, self._on_policy)

    def _on_policy(self, update: PolicyUpdate) -> None:
        with self._lock:
            self.versions.append(int(update.version))

    def seen(self) -> list[int]:
        with self._lock:
            return list(self.versions)


def test_learner_killed_just_after_a_checkpoint_resumes_exactly(cluster: Cluster, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    watch = PolicyWatch(cluster)
    try:
        # Checkpoints and broadcasts out of phase, so a checkpoint holds increments not merged yet and versions go
        # out between checkpoints, as with the defaults (3 s and 5 s).
        first = cluster.learner(run_dir, "--broadcast-interval", "0.7", "--checkpoint-interval", "2")
        # Outboxes that never fill: the actors keep handing in increments between checkpoints instead of waiting.
        actors = [
            cluster.actor(f"actor-{i}", "--learn", robots, "--outbox-limit", "100000")
            for i, robots in enumerate(["0-4", "5-9"])
        ]
        wait_for(lambda: checkpoint_version(run_dir) >= 3, 120, "a checkpointed policy with increments")
        # The worst moment: just after a checkpoint landed, once versions went out that it does not hold.
        landed = (run_dir / "checkpoint.npz").stat().st_mtime_ns
        wait_for(lambda: (run_dir / "checkpoint.npz").stat().st_mtime_ns != landed, 30, "the next checkpoint")
        saved = checkpoint_version(run_dir)
        wait_for(lambda: VersionMark(run_dir).load() > saved + 1, 30, "broadcasts after the checkpoint")
        first.kill()
        first.wait()
        published_before = VersionMark(run_dir).load()
        seen_before = len(watch.seen())
        saved_version = checkpoint_version(run_dir)
        assert published_before > saved_version  # versions went out after the checkpoint: the hard case
        time.sleep(2.0)  # the actors go on producing into their outboxes with no learner
        second = cluster.learner(run_dir, "--resume", "--broadcast-interval", "0.7", "--checkpoint-interval", "2")
        wait_for(lambda: checkpoint_version(run_dir) > published_before + 3, 90, "the resumed learner to broadcast")
        statuses = [finish(a, sig=signal.SIGTERM) for a in actors]
        report = finish(second, sig=signal.SIGTERM)
    finally:
        watch.transport.close()
    versions = watch.seen()
    assert versions[seen_before:] and min(versions[seen_before:]) > published_before
    assert versions == sorted(set(versions))  # strictly increasing across the restart, as seen on the wire
    # The resumed learner's very first broadcast (sent before this test's session could reconnect) is above every
    # version the killed one sent: the learner logs it as it starts.
    started = [int(v) for v in re.findall(r"started \(policy version (\d+)\)", (tmp_path / "learner.log").read_text())]
    assert len(started) == 2 and started[0] == 0 and started[1] > published_before
    # Exactly once: every tuple sent is stored once, and all of it was acknowledged.
    assert all(s["outbox"] == 0 for s in statuses)
    assert report["gaps"] == 0
    for i, s in enumerate(statuses):
        assert report["tuples_by_actor"][f"actor-{i}"] == s["tuples_sent"] == s["tuples_acked"]
    # Every acknowledged increment's visits are in the final tables, and none twice.
    policy, _ = load_policy(report["policy_file"])
    assert policy.visits is not None
    assert int(policy.visits.astype(np.int64).sum()) == sum(s["visits_acked"] for s in statuses) > 0
    assert report["stale_increments"] == 0
    # The clock goes on: the curve and the run's seconds count the killed learner's time too.
    times = [t for t, _ in report["coverage_curve"]]
    assert times == sorted(times)
    assert report["policy_version"] > published_before


def test_a_peer_sending_under_another_actors_identity_stores_nothing(cluster: Cluster, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    learner = cluster.learner(run_dir)
    actor = cluster.actor("actor-0", "--learn", "0-9")
    wait_for(lambda: checkpoint_version(run_dir) >= 1, 120, "a first policy")
    conf = zenoh_config(connect=[cluster.endpoint], mode="peer", multicast_scouting=False)
    keys = KeySpace(cluster.namespace)
    n = 7
    lie = ExperienceBatch(
        actor_id="actor-0",  # the genuine actor's id, on the liar's own key
        incarnation=1,
        seq=0,
        policy_version=0,
        robot=np.zeros(n, np.int16),
        state=np.zeros((n, 6), np.float32),
        action=np.zeros(n, np.uint8),
        reward=np.zeros(n, np.float32),
        next_state=np.zeros((n, 6), np.float32),
        done=np.zeros(n, bool),
    )
    with ZenohTransport.open(conf, keys) as liar:
        wait_for(lambda: liar.has_subscribers(keys.experience("mallory")), 30, "the learner's subscription")
        for _ in range(5):
            liar.session.put(keys.experience("mallory"), _encoded(lie))  # past our own publish-side check
        time.sleep(1.0)
    status = finish(actor, sig=signal.SIGTERM)
    report = finish(learner, sig=signal.SIGTERM)
    assert report["rejected_by_type"].get("IdentityMismatch") == 5
    assert set(report["tuples_by_actor"]) == {"actor-0"}
    assert report["tuples_by_actor"]["actor-0"] == status["tuples_sent"]  # the genuine stream is whole
    assert report["duplicates"] == 0  # nothing of the genuine stream was suppressed as a duplicate


def _encoded(msg: ExperienceBatch) -> bytes:
    from protocol import encode

    return encode(msg)


def test_a_poisoned_message_is_rejected_and_its_stream_flows_on(cluster: Cluster, tmp_path: Path) -> None:
    """A client written against docs/protocol.md sends seq 0, a NaN batch at seq 1, then seq 2."""
    import msgpack

    from protocol import Ack, Reject, encode

    learner = cluster.learner(tmp_path / "run")
    keys = KeySpace(cluster.namespace)
    n = 5

    def batch(seq: int) -> bytes:
        data = encode(
            ExperienceBatch(
                actor_id="client-7",
                incarnation=99,
                seq=seq,
                policy_version=0,
                robot=np.zeros(n, np.int16),
                state=np.ones((n, 6), np.float32),
                action=np.zeros(n, np.uint8),
                reward=np.zeros(n, np.float32),
                next_state=np.ones((n, 6), np.float32),
                done=np.zeros(n, bool),
            )
        )
        if seq != 1:
            return data
        envelope = msgpack.unpackb(data, raw=False)
        envelope[2]["reward"] = ["float32", [n], np.full(n, np.nan, np.float32).tobytes()]
        return msgpack.packb(envelope, use_bin_type=True)

    rejects: list[int] = []
    acks: list[int] = []
    conf = zenoh_config(connect=[cluster.endpoint], mode="peer", multicast_scouting=False)
    with ZenohTransport.open(conf, keys) as client:
        client.subscribe(keys.reject("client-7"), Reject, lambda r: rejects.append(r.seq))
        client.subscribe(keys.ack("client-7"), Ack, lambda a: acks.append(a.seq))
        wait_for(lambda: client.has_subscribers(keys.experience("client-7")), 60, "the learner's subscription")
        for seq in (0, 1, 2):
            client.session.put(keys.experience("client-7"), batch(seq))
        wait_for(lambda: 1 in rejects and max(acks, default=-1) >= 2, 60, "the Reject of seq 1 and the ack of seq 2")
    report = finish(learner, sig=signal.SIGTERM)
    assert rejects == [1]
    assert report["tuples_by_actor"]["client-7"] == 2 * n and report["gaps"] == 0
    assert report["rejected_by_type"] == {"InvalidValues": 1}
