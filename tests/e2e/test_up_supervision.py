"""``ennc-ql up --secure`` supervises its children: a killed actor is reported at once and restarted, so is the
router (and every client authenticates to the new one); a dead learner ends the run with a non-zero exit and the end
of its log (one run, all three faults)."""

from __future__ import annotations

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


def child_pid(config: Path, timeout: float = 120.0) -> int:
    """The pid of the child of ``up`` started with the configuration file ``config``, once it runs."""
    needle = str(config).encode()
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
    raise AssertionError(f"no process with {config} appeared")


def wait_for_log(path: Path, text: str, timeout: float = 120.0, count: int = 1) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and path.read_text(errors="replace").count(text) >= count:
            return
        time.sleep(0.2)
    raise AssertionError(f"{text!r} never appeared in {path}")


def test_a_killed_actor_and_router_are_restarted_and_a_dead_learner_ends_the_run(tmp_path: Path) -> None:
    run_dir, err_path = tmp_path / "sup", tmp_path / "up.err"
    argv = ennc_ql("up", "--secure", "--duration=300", *SMALL, f"--runs={tmp_path}", "--run-id=sup")
    with open(err_path, "w") as err_file:
        up = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err_file, text=True)
        try:
            wait_for_log(run_dir / "actor-0.log", "incarnation")
            os.kill(child_pid(run_dir / "actor-0.toml"), signal.SIGKILL)
            wait_for_log(err_path, "actor-0 exited with status -9; restarting in 1 s")
            # The restarted actor is a new incarnation under the same id, with its own log lines.
            wait_for_log(run_dir / "actor-0.log", "incarnation", count=2)
            # The router: its clients (learner, two actors, up's own observer) authenticate to the new one.
            router_log = run_dir / "router.log"
            wait_for_log(router_log, " connected", count=4)
            os.kill(child_pid(run_dir / "secure" / "router.json5"), signal.SIGKILL)
            wait_for_log(err_path, "router exited with status -9; restarting in 1 s")
            wait_for_log(router_log, " connected", count=8)
            wait_for_log(run_dir / "learner.log", "learner learner started")
            os.kill(child_pid(run_dir / "learner.toml"), signal.SIGKILL)
            up.wait(timeout=120)
        finally:
            if up.poll() is None:
                up.kill()
                up.wait()
    err = err_path.read_text()
    assert up.returncode == 2
    assert "ennc-ql up: error: the learner exited with status -9" in err
    last_line = (run_dir / "learner.log").read_text().strip().splitlines()[-1]
    assert last_line in err  # the end of its log comes with the message
