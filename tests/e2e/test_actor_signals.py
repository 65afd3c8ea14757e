"""A standalone actor stops on Ctrl-C after flushing its outbox; a second Ctrl-C cuts that flush short.

No learner runs, so nothing the actor sends is ever acknowledged and its flush would wait its whole --flush-timeout
(here far longer than the test waits): only the second signal can end it in time.
"""

from __future__ import annotations

import signal
from pathlib import Path

from tests.e2e.cluster import Cluster, finish, wait_for


def _log(tmp: Path, ident: str) -> str:
    return (tmp / f"{ident}.log").read_text()


def test_a_second_ctrl_c_cuts_the_actors_flush_and_it_still_reports(cluster: Cluster, tmp_path: Path) -> None:
    actor = cluster.actor("a0", "--flush-timeout", "3600")
    wait_for(lambda: "arenas, learning robots" in _log(tmp_path, "a0"), 120, "the actor's trials to start")
    actor.send_signal(signal.SIGINT)
    wait_for(lambda: "received SIGINT, stopping" in _log(tmp_path, "a0"), 60, "the first Ctrl-C to be handled")
    status = finish(actor, timeout=120, sig=signal.SIGINT)
    log = _log(tmp_path, "a0")
    assert "received SIGINT again while stopping" in log
    # It sent experience, none of it was acknowledged, and it says what it drops instead of hiding it.
    assert status["tuples_sent"] > 0 and status["tuples_acked"] == 0
    assert "stops with" in log and "unacknowledged messages" in log
