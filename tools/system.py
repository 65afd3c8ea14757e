"""Process plumbing shared by every command: the signal handlers (a process's own, and a launcher's that counts its
interrupts), a child's death with its launcher, and the one free-port helper."""

from __future__ import annotations

import ctypes
import faulthandler
import itertools
import logging
import os
import random
import signal
import socket
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType

log = logging.getLogger(__name__)

PARENT_PID_ENV = "ENNC_QL_PARENT_PID"
"""Set by a launcher that owns its children (``up``) to its own pid: the child then dies with it."""
_PR_SET_PDEATHSIG = 1
INTERRUPTS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""What stops a launcher: Ctrl-C, what job runners, ``timeout`` and systemd send, and a closed terminal."""


def set_from_handler(event: threading.Event) -> None:
    """``event.set()`` for a signal handler, on a thread of its own. A handler runs on the main thread between two
    bytecodes, possibly inside ``event.wait()`` just as that has taken back the event's lock: ``set()`` there waits for
    that lock forever (a learner hung so on SIGTERM, its stack dump showed). From another thread it waits only until
    the main thread's ``wait`` releases it."""
    threading.Thread(target=event.set, name=f"set-{id(event):x}", daemon=True).start()


class Stop(threading.Event):
    """Set by the first stopping signal: wind down. ``urgent`` is set by the next one: cut short what winding down
    still waits for (an actor's outbox flush), as a user who presses Ctrl-C again asks."""

    def __init__(self) -> None:
        super().__init__()
        self.urgent = threading.Event()


def stop_on_signals() -> Stop:
    """An event set by SIGTERM, SIGINT or SIGUSR1 (the process then winds down instead of dying mid-write), its
    ``urgent`` by a second one. SIGUSR1 is for SLURM: ``srun`` forwards it to its task, while it turns a SIGTERM into
    killing the job step. SIGQUIT dumps every thread's stack to stderr."""
    stop = Stop()
    received = itertools.count(1)

    def handler(signum: int, _frame: object) -> None:
        # Signals that arrive together land inside one another's handler, between any two bytecodes: each call
        # takes its number in one step (next() on a count is one C call) and every call sets the stop, so no
        # interleaving leaves the process running (an actor whose launcher was killed once took only "again"s and
        # ran on with a full outbox).
        n = next(received)
        set_from_handler(stop)
        name = signal.Signals(signum).name
        if n > 1:
            log.warning("received %s again while stopping", name)
            set_from_handler(stop.urgent)
            return
        log.info("received %s, stopping", name)

    signal.signal(signal.SIGTERM, handler)
    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGUSR1, handler)
    # A process that overruns its stop shows where it hangs: SIGQUIT writes every thread's stack to stderr (a
    # launched child's log) and the process goes on; its launcher sends it before killing it.
    faulthandler.register(signal.SIGQUIT, all_threads=True)
    return stop


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now, below Linux's ephemeral range so Zenoh's own sockets cannot take it."""
    # A random start: two processes asking at once (the suite's parallel workers) rarely get the same port before
    # either has bound it.
    for port in range(random.randrange(20000, 29000), 32000):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free TCP port in 20000-32000 on {host}")


def die_with_parent() -> None:
    """In a child of a launcher that owns its children: Linux sends this process SIGTERM (its own clean stop) when the
    launcher dies, however it dies; and if the launcher is gone already, this process exits now. Nothing elsewhere."""
    parent = os.environ.pop(PARENT_PID_ENV, None)  # not passed on to this process's own children
    if not parent or not parent.isdigit() or not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        log.warning("could not ask for a parent-death signal: %s", os.strerror(ctypes.get_errno()))
    if os.getppid() != int(parent):  # the launcher died before the request: nobody would ever stop this process
        raise SystemExit(f"ennc-ql: the process that started this one ({parent}) is gone; not starting")


class Interrupts:
    """A launcher's Ctrl-C, SIGTERM and SIGHUP, counted: the first sets :attr:`stop` (the run winds down cleanly),
    each further one runs the next escalation step (kill the actors, then the learner); the launcher always waits
    for its children. Usage::

        interrupts = Interrupts(say=lambda line: os.write(2, line.encode()))
        with interrupts.installed():
            interrupts.escalate(kill_actors, kill_learner)      # once the children exist
            run(stop=interrupts.stop)
        interrupts.first                                        # signal.SIGTERM, or None
        interrupts.exit_code                                    # 128 + its number (130, 143, 129), or 0
    """

    def __init__(self, say: Callable[[str], None] | None = None) -> None:
        self.stop = threading.Event()
        self.received: list[signal.Signals] = []
        self._count = itertools.count(1)
        self._say = say or (lambda line: log.warning("%s", line))
        self._steps: list[Callable[[], str]] = []

    @property
    def first(self) -> signal.Signals | None:
        return self.received[0] if self.received else None

    @property
    def exit_code(self) -> int:
        """The shell's status of a process ended by the first signal: 128 + its number."""
        return 0 if self.first is None else 128 + int(self.first)

    def escalate(self, *steps: Callable[[], str]) -> None:
        """What the second, third, ... signal does; each step returns the line that says what it did."""
        self._steps = list(steps)

    def handle(self, signum: int, _frame: FrameType | None = None) -> None:
        # As stop_on_signals' handler: its number in one step, and every call sets the stop.
        n = next(self._count)
        set_from_handler(self.stop)
        sig = signal.Signals(signum)
        self.received.append(sig)
        if n == 1:
            self._say(
                f"{sig.name}: winding down cleanly (the learner checkpoints and scores its policy); again to "
                "stop sooner"
            )
        elif n - 2 < len(self._steps):
            self._say(f"{sig.name} again: {self._steps[n - 2]()}")

    @contextmanager
    def installed(self) -> Iterator[Interrupts]:
        """:meth:`handle` for :data:`INTERRUPTS` while the block runs, the previous handlers after it."""
        previous = {sig: signal.signal(sig, self.handle) for sig in INTERRUPTS}
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
