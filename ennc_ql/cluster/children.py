"""Child processes of a run, by name: the one start-up skeleton of ``up``, ``chaos`` and the end-to-end tests.

Each child's stderr is appended to ``DIR/<name>.log``; with ``keep_stdout`` each incarnation's stdout goes to
``DIR/<name>.<k>.out`` (what a ``--json`` process printed), else nowhere. Usage::

    children = Children(run_dir)
    children.start("learner", ennc_ql_argv("learner", "--config", str(run_dir / "learner.toml")))
    children.start("actor-0", ennc_ql_argv("actor", ...), nice=ACTOR_NICENESS)
    children.running()                       # name -> pid of every child running now
    children.stop("actor-0", grace=10.0)     # SIGTERM, SIGKILL past the grace; its exit status
    children.close()                         # whatever happened: every child stopped and reaped

:class:`Supervisor` restarts the children that may die under ``up`` (the actors, the router).
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from protocol.security import ROUTER

log = logging.getLogger(__name__)

ACTOR_NICENESS = 10
"""Actors produce experience faster than one learner digests it on a shared machine: they yield the CPU to the
learner so phase 1 and evaluations are not starved."""


def ennc_ql_argv(*argv: str) -> list[str]:
    """The command line of ``ennc-ql ARGV`` with this interpreter (no reliance on PATH or the console script)."""
    return [sys.executable, "-m", "ennc_ql.cli", *argv]


def log_tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


class Children:
    def __init__(self, log_dir: Path, keep_stdout: bool = False, grace: float = 10.0) -> None:
        self.log_dir = log_dir
        self.keep_stdout = keep_stdout
        self.grace = grace
        """Seconds :meth:`close` gives the children still running between SIGTERM and SIGKILL (0: SIGKILL at once)."""
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        """The current incarnation of each name."""
        self.started: dict[str, float] = {}
        """Monotonic start time of each name's current incarnation."""
        self._incarnations: dict[str, int] = {}
        self._lock = threading.Lock()  # an RSS sampler may read the processes from its own thread

    def start(self, name: str, argv: list[str], nice: int = 0) -> subprocess.Popen[bytes]:
        """Start ``argv`` (a whole command line) under ``name``, at ``nice``; a name started again is its next
        incarnation."""
        k = self._incarnations.get(name, 0) + 1
        with open(self.log_dir / f"{name}.log", "a") as err:
            if self.keep_stdout:
                with open(self.stdout(name, k), "w") as out:
                    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err)
            else:
                proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        if nice:
            # From here rather than a preexec_fn, which is unsafe once this process has threads (restarts happen then).
            os.setpriority(os.PRIO_PROCESS, proc.pid, nice)
        with self._lock:
            self.procs[name] = proc
            self._incarnations[name] = k
            self.started[name] = time.monotonic()
        return proc

    def stdout(self, name: str, k: int | None = None) -> Path:
        """The stdout file of ``name``'s incarnation ``k`` (default: the current one), with ``keep_stdout``."""
        return self.log_dir / f"{name}.{k or self._incarnations[name]}.out"

    def running(self) -> dict[str, int]:
        """Name -> pid of every child running now."""
        with self._lock:
            return {name: p.pid for name, p in self.procs.items() if p.poll() is None}

    def exited(self) -> list[str]:
        """The children that are not running any more."""
        with self._lock:
            return [name for name, p in self.procs.items() if p.poll() is not None]

    def signal(self, name: str, sig: int) -> None:
        if self.procs[name].poll() is None:
            self.procs[name].send_signal(sig)

    def kill(self, name: str) -> None:
        self.procs[name].kill()
        self.procs[name].wait()

    def wait(self, name: str, timeout: float) -> int:
        """The exit status of ``name`` within ``timeout`` seconds, SIGKILLed past it (then -9)."""
        try:
            return self.procs[name].wait(timeout)
        except subprocess.TimeoutExpired:
            log.error("%s still running after %.0f s: killed; its log ends:\n%s", name, timeout, self.tail(name))
            self.kill(name)
            return self.procs[name].returncode

    def stop(self, name: str, grace: float) -> int:
        """SIGTERM, then SIGKILL if ``name`` still runs after ``grace`` seconds; its exit status."""
        self.signal(name, signal.SIGTERM)
        return self.wait(name, grace)

    def tail(self, name: str, lines: int = 15) -> str:
        return log_tail(self.log_dir / f"{name}.log", lines)

    def close(self) -> None:
        """Stop every child still running (SIGTERM, SIGKILL past ``grace``) and reap them all."""
        running = [p for p in self.procs.values() if p.poll() is None]
        for proc in running:
            proc.send_signal(signal.SIGCONT)  # a stopped child would not even die before it is continued
            if self.grace > 0:
                proc.terminate()
            else:
                proc.kill()
        deadline = time.monotonic() + self.grace
        for proc in running:
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


class Supervisor:
    """``up``'s restartable children (the actors, and the router of a secure run): one that exits while the run goes
    on is reported at once with the tail of its log and started again after a back-off (1, 2, 4 s, ...), at most
    ``max_restarts`` times; past that the run goes on without it, saying so. Usage (from the progress loop, once a
    second)::

        supervisor = Supervisor(children, max_restarts=3)
        supervisor.start("actor-0", argv, nice=ACTOR_NICENESS)   # for each restartable child
        for message in supervisor.check(): ...                   # what happened since the last check
        supervisor.stop_all()
    """

    def __init__(self, children: Children, max_restarts: int = 3) -> None:
        self.children = children
        self.max_restarts = max_restarts
        self.watched: dict[str, tuple[list[str], int]] = {}
        """Name -> (argv, niceness) of every child still supervised."""
        self.restarts: dict[str, int] = {}
        self._due: dict[str, float] = {}  # name -> when to start it again

    def start(self, name: str, argv: list[str], nice: int = 0) -> None:
        self.watched[name] = (argv, nice)
        self.children.start(name, argv, nice)

    def check(self) -> list[str]:
        messages = []
        now = time.monotonic()
        for name in list(self.watched):
            code = self.children.procs[name].poll()
            if code is None or name in self._due:
                continue
            n = self.restarts.get(name, 0)
            log.error("%s exited with status %s; its log ends:\n%s", name, code, self.children.tail(name))
            if n >= self.max_restarts:
                messages.append(f"{name} exited with status {code} again; not restarted ({n} restarts)")
                del self.watched[name]
                continue
            self._due[name] = now + 2.0**n
            messages.append(f"{name} exited with status {code}; restarting in {2**n} s")
        for name, due in list(self._due.items()):
            if now >= due:
                del self._due[name]
                self.restarts[name] = self.restarts.get(name, 0) + 1
                self.children.start(name, *self.watched[name])
        return messages

    def stop_all(self, grace: float = 10.0) -> None:
        # Actors first, the router last: actors flush their outboxes through it.
        for name in sorted(self.watched, key=lambda n: n == ROUTER):
            self.children.stop(name, grace)
