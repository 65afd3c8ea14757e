"""Process plumbing shared by every command: the one signal handler and the one free-port helper."""

from __future__ import annotations

import logging
import signal
import socket
import threading
import time

log = logging.getLogger(__name__)


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM or SIGINT (the process then winds down instead of dying mid-write)."""
    stop = threading.Event()

    def handler(signum: int, _frame: object) -> None:
        log.info("received %s, stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    return stop


def free_port() -> int:
    """A loopback TCP port that is free now, below Linux's ephemeral range so Zenoh's own sockets cannot take it."""
    for port in range(20000 + (int(time.time() * 1000) % 9000), 32000):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError("no free TCP port in 20000-32000 on 127.0.0.1")
