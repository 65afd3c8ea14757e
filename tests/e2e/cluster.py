"""Helpers of the end-to-end tests that run real ``ennc-ql`` processes on loopback Zenoh, imported by the tests that
need them (the ``cluster`` fixture is in ``conftest.py``)::

    c = Cluster(tmp_path)                                  # or the cluster fixture: every process killed at teardown
    learner = c.learner(run_dir)                           # FAST_LEARNER's settings, --listen on a free port
    actor = c.actor("a0")                                  # --connect to it
    wait_for(lambda: checkpoint_version(run_dir) >= 2, 120, "two policy versions")
    report = finish(learner, sig=signal.SIGINT)            # its --json report, exit status 0
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from tests.e2e import ACTOR_PACE
from tools.system import free_port

FAST_LEARNER = [
    "--min-tuples",
    "20000",
    "--phase1-max-patterns",
    "1500",
    "--phase1-n-cycles",
    "30",
    "--phase1-seed-prototypes",  # the default 512 seeds take the first fit 10-16 s on loaded cores
    "32",
    "--phase1-max-iterations",
    "1",
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
            "--max-tuples-per-s",
            ACTOR_PACE,
            *extra,
        )

    def kill_all(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.kill()
            proc.wait()


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
