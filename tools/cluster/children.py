"""Child processes of a run, by name: the one start-up skeleton of ``up``, ``chaos`` and the end-to-end tests.

Each child's stderr is appended to ``DIR/<name>.log``; with ``keep_stdout`` each incarnation's stdout goes to
``DIR/<name>.<k>.out`` (what a ``--json`` process printed), else nowhere. Usage::

    children = Children(run_dir)
    children.start("learner", ennc_ql_argv("learner", "--config", str(run_dir / "learner.toml")))
    children.start("actor-0", ennc_ql_argv("actor", ...), nice=ACTOR_NICENESS)
    children.running()                       # name -> pid of every child running now
    children.stop("actor-0", grace=10.0)     # SIGTERM, SIGKILL past the grace; its exit status
    children.close()                         # whatever happened: every child stopped and reaped

With ``own_group`` the children run in one process group of their own (a Ctrl-C at the terminal reaches only the
launcher, which decides what each child gets) and die with the launcher, whatever kills it: each is told the
launcher's pid (:data:`tools.system.PARENT_PID_ENV`) and asks Linux for SIGTERM when it dies
(:func:`tools.system.die_with_parent`).

:class:`Supervisor` restarts the children that may die under ``up`` (the learner, the actors, the router).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Container
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocol.security import ROUTER
from tools.system import PARENT_PID_ENV

log = logging.getLogger(__name__)

STACK_DUMP_S = 1.0
"""How long a child that overran its stop gets to write its stacks (SIGQUIT) before it is killed."""
STACK_DUMP_LINES = 80
"""Lines of its log quoted when it is killed: enough for the stacks of its main and Zenoh's threads."""
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
    def __init__(
        self,
        log_dir: Path,
        keep_stdout: bool | Container[str] = False,
        grace: float = 10.0,
        stop_signal: int = signal.SIGTERM,
        own_group: bool = False,
    ) -> None:
        self.log_dir = log_dir
        self.keep_stdout = keep_stdout
        """Whose stdout is kept: every child's (True), none (False), or the named children's."""
        self.grace = grace
        """Seconds :meth:`close` gives the children still running between the stop signal and SIGKILL (0: SIGKILL at
        once)."""
        self.stop_signal = stop_signal
        """What asks a child to wind down: SIGTERM, or SIGUSR1 for ``srun`` (which forwards it to its task, while it
        turns a SIGTERM into killing the job step)."""
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        """The current incarnation of each name."""
        self.started: dict[str, float] = {}
        """Monotonic start time of each name's current incarnation."""
        self.own_group = own_group
        self.group: int | None = None
        """The children's process group (``own_group``), once the first has started."""
        self._incarnations: dict[str, int] = {}
        self._lock = threading.Lock()  # an RSS sampler may read the processes from its own thread

    def start(self, name: str, argv: list[str], nice: int = 0) -> subprocess.Popen[bytes]:
        """Start ``argv`` (a whole command line) under ``name``, at ``nice``; a name started again is its next
        incarnation."""
        k = self._incarnations.get(name, 0) + 1
        with open(self.log_dir / f"{name}.log", "a") as err:
            if self.keep_stdout is True or (self.keep_stdout and name in self.keep_stdout):
                with open(self.stdout(name, k), "w") as out:
                    proc = self._popen(argv, out, err)
            else:
                proc = self._popen(argv, subprocess.DEVNULL, err)
        if nice:
            # From here rather than a preexec_fn, which is unsafe once this process has threads (restarts happen then).
            os.setpriority(os.PRIO_PROCESS, proc.pid, nice)
        with self._lock:
            self.procs[name] = proc
            self._incarnations[name] = k
            self.started[name] = time.monotonic()
        return proc

    def _popen(self, argv: list[str], out: Any, err: Any) -> subprocess.Popen[bytes]:
        if not self.own_group:
            return subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err)
        env = {**os.environ, PARENT_PID_ENV: str(os.getpid())}
        if self.group is not None:
            try:
                return subprocess.Popen(
                    argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env, process_group=self.group
                )
            except PermissionError:  # every member of the group has exited: the group is gone, start a new one
                pass
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env, process_group=0)
        self.group = proc.pid
        return proc

    def kill_now(self, names: Container[str]) -> list[str]:
        """SIGKILL every running child among ``names``, without waiting (whoever waits for them sees them end); the
        names killed."""
        killed = []
        for name, proc in list(self.procs.items()):
            if name in names and proc.poll() is None:
                proc.kill()
                killed.append(name)
        return killed

    def stdout(self, name: str, k: int | None = None) -> Path:
        """The stdout file of ``name``'s incarnation ``k`` (default: the current one), with ``keep_stdout``."""
        return self.log_dir / f"{name}.{k or self._incarnations[name]}.out"

    def incarnations(self, name: str) -> int:
        """How many times ``name`` was started (0: never)."""
        with self._lock:
            return self._incarnations.get(name, 0)

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
            # Where it hangs, before it dies: the children's stop_on_signals dump their stacks on SIGQUIT.
            self.procs[name].send_signal(signal.SIGQUIT)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.procs[name].wait(STACK_DUMP_S)
            stacks = self.tail(name, STACK_DUMP_LINES)
            log.error("%s still running after %.0f s: killed; its log and stacks end:\n%s", name, timeout, stacks)
            self.kill(name)
            return self.procs[name].returncode

    def stop(self, name: str, grace: float) -> int:
        """The stop signal, then SIGKILL if ``name`` still runs after ``grace`` seconds; its exit status."""
        self.signal(name, self.stop_signal)
        return self.wait(name, grace)

    def stop_many(self, names: list[str], grace: float) -> None:
        """:meth:`stop` for several children at once: they wind down side by side within one ``grace``."""
        names = [name for name in names if name in self.procs]
        for name in names:
            self.signal(name, self.stop_signal)
        deadline = time.monotonic() + grace
        for name in names:
            self.wait(name, max(0.0, deadline - time.monotonic()))

    def tail(self, name: str, lines: int = 15) -> str:
        return log_tail(self.log_dir / f"{name}.log", lines)

    def close(self) -> None:
        """Stop every child still running (SIGTERM, SIGKILL past ``grace``) and reap them all."""
        running = [p for p in self.procs.values() if p.poll() is None]
        for proc in running:
            proc.send_signal(signal.SIGCONT)  # a stopped child would not even die before it is continued
            if self.grace > 0:
                proc.send_signal(self.stop_signal)
            else:
                proc.kill()
        deadline = time.monotonic() + self.grace
        for proc in running:
            try:
                proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@dataclass(frozen=True, slots=True)
class Restart:
    """One end of a supervised child that the run went on from, as the run report lists it."""

    name: str
    status: int
    """The exit status of the incarnation that ended (-9: SIGKILL)."""
    ran_s: float
    """How long that incarnation had run."""
    noticed_at: float
    """Wall time (``time.time()``) its end was noticed."""
    delay_s: float
    """Back-off before the next incarnation started."""


class Supervisor:
    """A run's restartable children: one that exits while the run goes on is reported at once with the tail of its
    log and started again after a back-off (1, 2, 4 s, ...), with ``restart_argv`` if given (the learner: ``--resume
    auto``). ``max_restarts`` failures in a row end its supervision, saying so (it is then in :attr:`given_up`);
    an incarnation that ran ``stable_s`` seconds starts a new row, so a long run survives rare crashes while a
    crash loop (a learner on a bad checkpoint) ends. A child that exits 0 has finished: it is not restarted. Usage
    (from the progress loop, once a second)::

        supervisor = Supervisor(children, max_restarts=3)
        supervisor.start("actor-0", argv, nice=ACTOR_NICENESS)   # for each restartable child
        supervisor.start("learner", argv, restart_argv=[*argv, "--resume", "auto"])
        for message in supervisor.check(): ...                   # what happened since the last check
        supervisor.finished, supervisor.given_up, supervisor.events
        supervisor.stop(["actor-0"], grace=15.0)                 # stop some, unsupervised from now on
        supervisor.stop_all()
    """

    def __init__(self, children: Children, max_restarts: int = 3, stable_s: float = 60.0) -> None:
        self.children = children
        self.max_restarts = max_restarts
        self.stable_s = stable_s
        self.watched: dict[str, tuple[list[str], list[str], int]] = {}
        """Name -> (argv of the first start, argv of a restart, niceness) of every child still supervised."""
        self.restarts: dict[str, int] = {}
        """Restarts of each child over the run."""
        self.events: list[Restart] = []
        self.finished: set[str] = set()
        """Children that exited 0 by themselves."""
        self.given_up: dict[str, int] = {}
        """Children that failed ``max_restarts`` times in a row after a first failure, with their last exit status."""
        self._failures: dict[str, int] = {}  # name -> failures in a row
        self._due: dict[str, float] = {}  # name -> when to start it again

    def start(self, name: str, argv: list[str], nice: int = 0, restart_argv: list[str] | None = None) -> None:
        self.watched[name] = (argv, restart_argv or argv, nice)
        self.children.start(name, argv, nice)

    def check(self) -> list[str]:
        messages = []
        now = time.monotonic()
        for name in list(self.watched):
            code = self.children.procs[name].poll()
            if code is None or name in self._due:
                continue
            if code == 0:
                self.finished.add(name)
                del self.watched[name]
                continue
            ran = now - self.children.started[name]
            failures = 1 if ran >= self.stable_s else self._failures.get(name, 0) + 1
            self._failures[name] = failures
            log.error("%s exited with status %s; its log ends:\n%s", name, code, self.children.tail(name))
            if failures > self.max_restarts:
                messages.append(f"{name} exited with status {code} again; not restarted ({failures - 1} restarts)")
                self.given_up[name] = code
                del self.watched[name]
                continue
            delay = 2.0 ** (failures - 1)
            self._due[name] = now + delay
            self.events.append(Restart(name, code, round(ran, 1), time.time(), delay))
            messages.append(f"{name} exited with status {code}; restarting in {delay:g} s")
        for name, due in list(self._due.items()):
            if now >= due:
                del self._due[name]
                self.restarts[name] = self.restarts.get(name, 0) + 1
                _, argv, nice = self.watched[name]
                self.children.start(name, argv, nice)
        return messages

    def stop(self, names: list[str], grace: float = 10.0) -> None:
        """Stop ``names`` together (the stop signal to each, then a shared grace) and supervise them no more."""
        for name in names:
            self.watched.pop(name, None)
            self._due.pop(name, None)
        self.children.stop_many(names, grace)

    def stop_all(self, grace: float = 10.0) -> None:
        # Actors first, the router last: actors flush their outboxes through it.
        names = list(self.watched)
        self.stop([n for n in names if n != ROUTER], grace)
        self.stop([n for n in names if n == ROUTER], grace)
