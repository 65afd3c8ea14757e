"""Process plumbing shared by every command: the one signal handler and the one free-port helper."""

from __future__ import annotations

import logging
import signal
import socket
import threading
import time

log = logging.getLogger(__name__)


def stop_on_signals() -> threading.Event:
    """An event set by SIGTERM, SIGINT or SIGUSR1 (the process then winds down instead of dying mid-write). SIGUSR1 is
    for SLURM: ``srun`` forwards it to its task, while it turns a SIGTERM into killing the job step."""
    stop = threading.Event()

    def handler(signum: int, _frame: object) -> None:
        log.info("received %s, stopping", signal.Signals(signum).name)
        stop.set()

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGUSR1, handler)
    return stop


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now, below Linux's ephemeral range so Zenoh's own sockets cannot take it."""
    for port in range(20000 + (int(time.time() * 1000) % 9000), 32000):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free TCP port in 20000-32000 on {host}")
