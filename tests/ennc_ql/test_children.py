"""The child processes of a run: one that exits is reported with its log, restarted with back-off, then given up;
and whatever happens, closing stops every child still running."""

from __future__ import annotations

import logging
import signal
import sys
import time
from pathlib import Path

import pytest

from tools.cluster import Children, Supervisor, ennc_ql_argv


def test_an_exiting_actor_is_restarted_with_back_off_then_given_up(tmp_path: Path) -> None:
    # A child that fails at once: its configuration names a robot that does not exist.
    supervisor = Supervisor(Children(tmp_path), max_restarts=1)
    supervisor.start("a0", ennc_ql_argv("actor", "--actor-id", "a0", "--learn", "99"))
    messages: list[str] = []
    deadline = time.monotonic() + 120
    while "a0" in supervisor.watched and time.monotonic() < deadline:
        messages += supervisor.check()
        time.sleep(0.1)
    assert messages == [
        "a0 exited with status 2; restarting in 1 s",
        "a0 exited with status 2 again; not restarted (1 restarts)",
    ]
    assert supervisor.restarts == {"a0": 1}
    assert (tmp_path / "a0.log").read_text().count("do not all exist") == 2  # both runs logged, appended


def test_close_stops_every_child_even_a_stopped_one_and_each_incarnation_keeps_its_stdout(tmp_path: Path) -> None:
    children = Children(tmp_path, keep_stdout=True, grace=5.0)
    sleeper = [sys.executable, "-c", "import time; print('up', flush=True); time.sleep(600)"]
    children.start("a", sleeper)
    children.start("b", sleeper)
    children.signal("b", signal.SIGSTOP)  # a stopped child ignores SIGTERM until it is continued
    deadline = time.monotonic() + 60
    while children.stdout("a").read_text() != "up\n" and time.monotonic() < deadline:
        time.sleep(0.05)
    children.kill("a")
    children.start("a", [sys.executable, "-c", "print('again')"])
    assert children.wait("a", timeout=60) == 0
    assert (children.stdout("a", 1).read_text(), children.stdout("a").read_text()) == ("up\n", "again\n")
    assert children.exited() == ["a"] and list(children.running()) == ["b"]
    children.close()
    assert children.running() == {} and children.procs["b"].returncode == -signal.SIGTERM


def test_a_restart_runs_its_own_command_and_a_child_that_exits_0_has_finished(tmp_path: Path) -> None:
    # The first start fails; the restart (the learner's --resume auto, here another command line) succeeds.
    supervisor = Supervisor(Children(tmp_path, keep_stdout=True), max_restarts=3)
    fail = [sys.executable, "-c", "print('first'); raise SystemExit(3)"]
    supervisor.start("l", fail, restart_argv=[sys.executable, "-c", "print('resumed')"])
    messages: list[str] = []
    deadline = time.monotonic() + 60
    while "l" not in supervisor.finished and time.monotonic() < deadline:
        messages += supervisor.check()
        time.sleep(0.1)
    assert messages == ["l exited with status 3; restarting in 1 s"]
    assert supervisor.finished == {"l"} and supervisor.given_up == {} and supervisor.restarts == {"l": 1}
    [event] = supervisor.events
    assert (event.name, event.status, event.delay_s) == ("l", 3, 1.0)
    children = supervisor.children
    assert (children.stdout("l", 1).read_text(), children.stdout("l", 2).read_text()) == ("first\n", "resumed\n")


def test_a_child_that_overruns_its_stop_leaves_its_stacks_in_its_log_before_it_is_killed(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # What every ennc-ql process installs (stop_on_signals), then a hang that ignores the stop.
    hangs = "from tools.system import stop_on_signals\nimport time\nstop_on_signals()\ndef stuck_here():\n"
    hangs += "    print('up', flush=True)\n    time.sleep(600)\nstuck_here()\n"
    children = Children(tmp_path, keep_stdout=True)
    children.start("l", [sys.executable, "-c", hangs])
    deadline = time.monotonic() + 60
    while children.stdout("l").read_text() != "up\n" and time.monotonic() < deadline:
        time.sleep(0.05)
    with caplog.at_level(logging.ERROR, logger="tools.cluster.children"):
        assert children.stop("l", grace=1.0) == -signal.SIGKILL
    log = (tmp_path / "l.log").read_text()
    assert "most recent call first" in log and "in stuck_here" in log
    assert "in stuck_here" in caplog.text and "still running after 1 s" in caplog.text
