"""The launcher's supervisor: a child that exits is reported with its log, restarted with back-off, then given up."""

from __future__ import annotations

import time
from pathlib import Path

from ennc_ql.launch import Supervisor


def test_an_exiting_actor_is_restarted_with_back_off_then_given_up(tmp_path: Path) -> None:
    # A child that fails at once: its configuration names a robot that does not exist.
    supervisor = Supervisor(tmp_path, max_restarts=1)
    supervisor.start("a0", ["actor", "--actor-id", "a0", "--learn", "99"])
    messages: list[str] = []
    deadline = time.monotonic() + 120
    while "a0" in supervisor.procs and time.monotonic() < deadline:
        messages += supervisor.check()
        time.sleep(0.1)
    assert messages == [
        "a0 exited with status 2; restarting in 1 s",
        "a0 exited with status 2 again; not restarted (1 restarts)",
    ]
    assert supervisor.restarts == {"a0": 1}
    assert (tmp_path / "a0.log").read_text().count("do not all exist") == 2  # both runs logged, appended
