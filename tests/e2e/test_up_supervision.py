"""``ennc-ql up`` supervises its children: a killed actor is reported at once and restarted; a dead learner ends
the run with a non-zero exit and the end of its log."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from tests.e2e import ennc_ql

pytestmark = pytest.mark.slow

SMALL = [
    "--actors=2",
    "--actor-arenas=16",
    "--actor-batch-size=1024",
    "--learner-min-tuples=5000",
    "--learner-phase1-max-patterns=300",
    "--learner-phase1-n-cycles=10",
    "--learner-eval-interval=1000",
    "--learner-eval-trials=1",
    "--learner-final-eval-trials=2",
    "--rerun=off",
    "--json",
]


def child_pid(run_dir: Path, name: str, timeout: float = 120.0) -> int:
    """The pid of the child of ``up`` started with ``<run_dir>/<name>.toml``, once it runs."""
    needle = str(run_dir / f"{name}.toml").encode()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit():
                try:
                    if needle in (entry / "cmdline").read_bytes():
                        return int(entry.name)
                except OSError:
                    continue
        time.sleep(0.2)
    raise AssertionError(f"no process of {name} appeared")


def wait_for_log(path: Path, text: str, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and text in path.read_text(errors="replace"):
            return
        time.sleep(0.2)
    raise AssertionError(f"{text!r} never appeared in {path}")


def start_up(tmp_path: Path, duration: int) -> subprocess.Popen[str]:
    argv = ennc_ql("up", f"--duration={duration}", *SMALL, f"--runs={tmp_path}", "--run-id=sup")
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_killed_actor_is_reported_and_restarted(tmp_path: Path) -> None:
    run_dir = tmp_path / "sup"
    up = start_up(tmp_path, duration=40)
    try:
        wait_for_log(run_dir / "actor-0.log", "incarnation")
        os.kill(child_pid(run_dir, "actor-0"), signal.SIGKILL)
        out, err = up.communicate(timeout=300)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    assert up.returncode == 0, err[-3000:]
    assert "actor-0 exited with status -9; restarting in 1 s" in err
    report = json.loads(out.strip().splitlines()[-1])
    assert report["actor_restarts"] == {"actor-0": 1}
    # The restarted actor (a new incarnation under the same id) streamed again and learned on.
    assert (run_dir / "actor-0.log").read_text().count("incarnation") == 2
    assert report["tuples_by_actor"]["actor-0"] > 0 and report["live_actors"] == ["actor-0", "actor-1"]


def test_a_dead_learner_ends_the_run_with_its_log(tmp_path: Path) -> None:
    run_dir = tmp_path / "sup"
    up = start_up(tmp_path, duration=300)
    try:
        wait_for_log(run_dir / "learner.log", "learner learner started")
        os.kill(child_pid(run_dir, "learner"), signal.SIGKILL)
        _, err = up.communicate(timeout=120)
    finally:
        if up.poll() is None:
            up.kill()
            up.communicate()
    assert up.returncode == 2
    assert "ennc-ql up: error: the learner exited with status -9" in err
    assert "learner learner started" in err  # the end of its log comes with the message
