"""End-to-end: real ``ennc-ql learner`` and ``ennc-ql actor`` processes on loopback Zenoh.

Asserted outcomes: tuples counted equal tuples sent, policy versions advance, a late actor gets the current
policy at once, killing an actor does not stop learning, and a learner killed and restarted with ``--resume``
continues from its checkpoint while the actors' outboxes fill every gap.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest

from tests.e2e.cluster import Cluster, checkpoint_version, finish, wait_for

pytestmark = pytest.mark.slow


def test_experience_flows_versions_advance_late_actor_and_killed_actor(cluster: Cluster, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    learner = cluster.learner(run_dir)
    a0 = cluster.actor("actor-0", "--learn", "0-4", "--duration", "45")
    a1 = cluster.actor("actor-1", "--learn", "5-9")
    wait_for(lambda: checkpoint_version(run_dir) >= 2, 90, "a policy from the learner")
    a1.kill()  # SIGKILL: its liveliness token vanishes at once; learning must go on with actor-0
    a1.wait()
    version_at_kill = checkpoint_version(run_dir)
    late = cluster.actor("actor-late", "--learn", "0-9", "--duration", "8")
    late_counters = finish(late)
    # The late actor got the current policy at once and applied it before its first trial ended.
    assert late_counters["policy_version"] >= version_at_kill
    assert late_counters["policies_applied"] >= 1
    a0_counters = finish(a0)
    report = finish(learner, sig=signal.SIGTERM)
    assert report["policy_version"] > version_at_kill  # versions kept advancing after the kill
    assert set(report["actors"]) == {"actor-0", "actor-1", "actor-late"}
    assert "actor-1" not in report["live_actors"]
    # Exactly once: everything the surviving actors sent was stored once, nothing more.
    assert report["tuples_by_actor"]["actor-0"] == a0_counters["tuples_sent"]
    assert report["tuples_by_actor"]["actor-late"] == late_counters["tuples_sent"]
    assert a0_counters["outbox"] == 0 and late_counters["outbox"] == 0
    assert report["gaps"] == 0 and report["rejected"] == 0
    assert report["final_coverage_mean"] is not None
    assert Path(report["policy_file"]).exists()


def test_learner_restarted_with_resume_continues_and_outboxes_fill_the_gap(cluster: Cluster, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    first = cluster.learner(run_dir)
    actors = [cluster.actor(f"actor-{i}", "--learn", robots) for i, robots in enumerate(["0-4", "5-9"])]
    wait_for(lambda: checkpoint_version(run_dir) >= 2, 90, "a checkpointed policy")
    first.kill()  # SIGKILL: no final checkpoint; everything after the last one is unacknowledged
    first.wait()
    version_before = checkpoint_version(run_dir)
    time.sleep(2.0)  # actors keep producing into their outboxes while no learner is there
    second = cluster.learner(run_dir, "--resume")
    wait_for(lambda: checkpoint_version(run_dir) > version_before + 3, 60, "the resumed learner to broadcast")
    counters = [finish(a, sig=signal.SIGTERM) for a in actors]
    report = finish(second, sig=signal.SIGTERM)
    assert report["policy_version"] > version_before
    assert report["gaps"] == 0
    assert all(c["outbox"] == 0 for c in counters)
    for i, c in enumerate(counters):
        assert report["tuples_by_actor"][f"actor-{i}"] == c["tuples_sent"]
    assert report["tuples_received"] == sum(c["tuples_sent"] for c in counters)
