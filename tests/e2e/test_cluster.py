"""End-to-end: real ``ennc-ql learner`` and ``ennc-ql actor`` processes on loopback Zenoh.

Asserted outcomes: tuples counted equal tuples sent, policy versions advance, a late actor gets the current
policy at once, killing an actor does not stop learning, and a learner killed and restarted with ``--resume``
continues from its checkpoint while the actors' outboxes fill every gap.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from ennc_ql.system import free_port

pytestmark = pytest.mark.slow

FAST_LEARNER = [
    "--min-tuples",
    "20000",
    "--phase1-max-patterns",
    "1500",
    "--phase1-n-cycles",
    "30",
    "--broadcast-interval",
    "1",
    "--checkpoint-interval",
    "1",
    "--eval-interval",
    "4",
    "--eval-trials",
    "2",
    "--status-interval",
    "1",
    "--threads",
    "1",
]


class Cluster:
    """Processes of one test, all killed at teardown."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.namespace = f"t{int(time.time() * 1000) % 10**9}"
        self.procs: list[subprocess.Popen[str]] = []

    def spawn(self, name: str, *argv: str) -> subprocess.Popen[str]:
        log = open(self.tmp / f"{name}.log", "a")  # noqa: SIM115 - closed with the process at teardown
        proc = subprocess.Popen(
            [sys.executable, "-m", "ennc_ql.cli", *argv, "--namespace", self.namespace, "--no-multicast-scouting"],
            stdout=subprocess.PIPE,
            stderr=log,
            text=True,
        )
        self.procs.append(proc)
        return proc

    def learner(self, run_dir: Path, *extra: str) -> subprocess.Popen[str]:
        return self.spawn(
            "learner", "learner", "--listen", self.endpoint, "--run-dir", str(run_dir), "--json", *FAST_LEARNER, *extra
        )

    def actor(self, ident: str, *extra: str) -> subprocess.Popen[str]:
        return self.spawn(
            ident,
            "actor",
            "--connect",
            self.endpoint,
            "--actor-id",
            ident,
            "--arenas",
            "32",
            "--json",
            "--batch-size",
            "512",
            "--flush-timeout",
            "30",
            *extra,
        )

    def kill_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait()


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    c = Cluster(tmp_path)
    try:
        yield c
    finally:
        c.kill_all()


def finish(proc: subprocess.Popen[str], timeout: float = 90.0, sig: int | None = None) -> dict:
    if sig is not None:
        proc.send_signal(sig)
    out, _ = proc.communicate(timeout=timeout)
    assert proc.returncode == 0, out
    return json.loads(out.strip().splitlines()[-1])


def wait_for(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.5)
    raise AssertionError(f"timed out waiting for {what}")


def checkpoint_version(run_dir: Path) -> int:
    import numpy as np

    path = run_dir / "checkpoint.npz"
    if not path.exists():
        return 0
    try:
        with np.load(path) as data:
            return int(json.loads(data["meta"].tobytes())["version"])
    except (OSError, ValueError, KeyError):
        return 0


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
