"""Faults at the worst moment, from outside: the learner SIGKILLed just after a checkpoint landed (the moment with
the most unsaved state), then resumed; a poisoned message from a client written from docs/reference/protocol.md alone.
(Spoofing, router restarts, stopped and killed actors, unauthenticated peers and oversize messages are
``ennc-ql chaos``'s, tested in test_chaos.py.)

Asserted: tuples exactly once; every acknowledged increment's visits are in the final tables; policy versions
strictly increase across the restart; the run's clock goes on from the checkpoint; the poisoned stream flows on.
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
from protocol import PolicyUpdate, ZenohTransport, zenoh_config
from protocol.keys import KeySpace
from tests.e2e.cluster import Cluster, checkpoint_version, finish, wait_for

pytestmark = pytest.mark.slow


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
        # out between checkpoints. Broadcasts every 0.5 s and checkpoints every 4 s leave about 3 s between the
        # second broadcast after a checkpoint and the next checkpoint for the kill below, on a loaded machine too.
        first = cluster.learner(run_dir, "--broadcast-interval", "0.5", "--checkpoint-interval", "4")
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
        second = cluster.learner(run_dir, "--resume", "--broadcast-interval", "0.5", "--checkpoint-interval", "4")
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
    # (Read from the final checkpoint: the policy file is the one kept on validation trials, maybe an earlier one.)
    with np.load(report["checkpoint"]) as checkpoint:
        assert "pending_visits" not in checkpoint.files or not checkpoint["pending_visits"].any()
        in_tables = int(checkpoint["visits"].astype(np.int64).sum())
    assert in_tables == sum(s["visits_acked"] for s in statuses) > 0
    load_policy(report["policy_file"])  # and the run saved a policy that loads
    assert report["stale_increments"] == 0
    # The clock goes on: the curve and the run's seconds count the killed learner's time too.
    times = [t for t, _ in report["coverage_curve"]]
    assert times == sorted(times)
    assert report["policy_version"] > published_before


def test_a_poisoned_message_is_rejected_and_its_stream_flows_on(cluster: Cluster, tmp_path: Path) -> None:
    """A client written from docs/reference/protocol.md alone (plain msgpack and zenoh, none of the project's protocol
    code) sends seq 0, a batch with NaN rewards at seq 1 twice (a re-send), then seq 2, and reads the learner's Reject
    and Ack; it also holds a liveliness token under an id that is not an identifier. One count per message: the poisoned
    one rejected once and its copy a duplicate; the token refused and logged once, and never listed."""
    import msgpack
    import zenoh

    learner = cluster.learner(tmp_path / "run")
    prefix = f"{cluster.namespace}/enncql/v2"
    n = 5

    def array(dtype: str, values: np.ndarray) -> list[object]:
        return [dtype, list(values.shape), values.astype(f"<{np.dtype(dtype).str[1:]}").tobytes()]  # §2

    def batch(seq: int) -> bytes:
        reward = np.full(n, np.nan if seq == 1 else 0.0)
        fields = {  # §4, in the listed order
            "actor_id": "client-7",
            "incarnation": 99,
            "seq": seq,
            "policy_version": 0,
            "featurizer": "frame11d-recall",  # the learner's formulation: frame-recall-track, by default
            "reward_function": "difference-redundancy",
            "action_set": "law-track",
            "robot": array("int16", np.zeros(n)),
            "state": array("float32", np.ones((n, 11))),
            "action": array("uint8", np.zeros(n)),
            "reward": array("float32", reward),
            "next_state": array("float32", np.ones((n, 11))),
            "done": array("bool", np.zeros(n, bool)),
        }
        return msgpack.packb([2, "experience", fields], use_bin_type=True)

    replies: list[tuple[str, int]] = []

    def on_reply(sample: zenoh.Sample) -> None:
        _, tag, fields = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
        replies.append((tag, fields["seq"]))

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", f'["{cluster.endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    log = tmp_path / "learner.log"
    with zenoh.open(conf) as session:
        token = session.liveliness().declare_token(f"{prefix}/alive/actor/-not-an-id")
        subscribers = [
            session.declare_subscriber(f"{prefix}/{channel}/client-7", on_reply) for channel in ("ack", "reject")
        ]
        publisher = session.declare_publisher(
            f"{prefix}/experience/client-7", congestion_control=zenoh.CongestionControl.BLOCK
        )
        wait_for(lambda: publisher.matching_status.matching, 60, "the learner's subscription")
        for seq in (0, 1, 1, 2):  # in order on one key: the copy of 1 is handled before 2 is stored
            publisher.put(batch(seq))
        wait_for(lambda: ("ack", 2) in replies and ("reject", 1) in replies, 60, "the Reject of 1 and the ack of 2")
        wait_for(lambda: "-not-an-id" in log.read_text(), 60, "the learner to refuse the token")
        publisher.undeclare()
        for subscriber in subscribers:
            subscriber.undeclare()
        token.undeclare()
    report = finish(learner, sig=signal.SIGTERM)
    assert [seq for tag, seq in replies if tag == "reject"] == [1]
    assert report["tuples_by_actor"]["client-7"] == 2 * n and report["gaps"] == 0
    assert report["rejected_by_type"] == {"InvalidValues": 1} and report["rejected"] == 1
    assert report["duplicates"] == 1
    assert report["refused_tokens"] == 1 and "-not-an-id" not in report["actors"]
    assert sum("-not-an-id" in line for line in log.read_text().splitlines()) == 1
