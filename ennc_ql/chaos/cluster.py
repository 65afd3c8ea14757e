"""The cluster chaos runs and watches: how every process joins the run through the router (:class:`Wiring`), the
OS processes (:class:`Children`), chaos's read-only session (:class:`Observer`), the RSS samples
(:class:`RssSampler`), and the waiting for what a fault expects."""

from __future__ import annotations

import json
import logging
import signal
import socket
import subprocess
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import psutil
import zenoh

from ennc_ql.launch import log_tail, spawn_child
from ennc_ql.secure import SecureSet, write_secure_set
from ennc_ql.system import free_port
from protocol import KeySpace, PolicyUpdate, Status, ZenohTransport, zenoh_config
from protocol.security import ROUTER

log = logging.getLogger("ennc_ql.chaos")  # one name for the package: its lines read "ennc_ql.chaos: ..."

MALLORY = "mallory"
"""The authenticated identity chaos plays as a hostile peer in a secure run (plain runs use one id per fault)."""

RECOVERY_TIMEOUT_S = 120.0
"""Longest wait for a restarted process (the learner loads torch and scikit-learn again) or a reply to a fault."""
STATUS_HISTORY = 512
"""Status messages kept per sender (17 minutes of them at the default 2 s): the faults look back seconds only."""

T = TypeVar("T")


# -- waiting ----------------------------------------------------------------------------------------------------------


class WaitTimeout(RuntimeError):
    """What chaos waited for did not happen in time (or a process it needs exited meanwhile): a fault is then
    recorded as failed and the run goes on; a cluster that does not start ends the run."""


def wait_for(what: str, timeout: float, probe: Callable[[], T | None]) -> T:
    """Poll ``probe`` every 0.2 s until it returns a true value (not None, False, 0 or empty); that value."""
    deadline = time.monotonic() + timeout
    while True:
        value = probe()
        if value:
            return value
        if time.monotonic() >= deadline:
            raise WaitTimeout(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.2)


def listening(port: int) -> bool:
    """Whether something accepts TCP connections on loopback ``port`` now."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def since(t: float) -> float:
    """Seconds from monotonic time ``t`` to now, rounded for the figures."""
    return round(time.monotonic() - t, 1)


# -- the processes ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Wiring:
    """How every process joins the run through the router on ``port``; ``secure`` holds the identities' files
    (None: plain TCP, nobody authenticated)."""

    port: int
    namespace: str
    secure: SecureSet | None

    @property
    def endpoint(self) -> str:
        return f"tls/localhost:{self.port}" if self.secure else f"tcp/127.0.0.1:{self.port}"

    def router_flags(self) -> list[str]:
        if self.secure:
            return ["--zenoh-config", str(self.secure.config(ROUTER))]
        return ["--listen", f"tcp/127.0.0.1:{self.port}"]

    def client_flags(self, ident: str) -> list[str]:
        flags = ["--zenoh-config", str(self.secure.config(ident))] if self.secure else ["--connect", self.endpoint]
        return [*flags, "--mode", "client", "--namespace", self.namespace, "--no-multicast-scouting"]

    def session(self, ident: str) -> zenoh.Config:
        """The configuration of a session of chaos's own as ``ident`` (observer, mallory; any id when plain)."""
        if self.secure:
            return zenoh_config(config_file=str(self.secure.config(ident)))
        return zenoh_config(connect=[self.endpoint], mode="client")

    def hostile(self, plain_id: str) -> str:
        """The id of a hostile peer: the authenticated mallory in a secure run, ``plain_id`` in a plain one."""
        return MALLORY if self.secure else plain_id

    def client_dict(self, ident: str) -> dict[str, Any]:
        """``ident``'s zenoh configuration as a dict, to derive broken ones from (secure runs only)."""
        assert self.secure is not None
        text = self.secure.config(ident).read_text()
        # write_secure_set writes a comment line, then plain JSON.
        conf: dict[str, Any] = json.loads("\n".join(ln for ln in text.splitlines() if not ln.startswith("//")))
        return conf


def make_wiring(run_dir: Path, namespace: str, learner_id: str, actor_ids: list[str], secure: bool) -> Wiring:
    port = free_port()
    if not secure:
        return Wiring(port, namespace, None)
    spec = SecureSet(
        folder=run_dir / "secure",
        actor_ids=(*actor_ids, MALLORY),
        learner_id=learner_id,
        namespace=namespace,
        listen=(f"tls/127.0.0.1:{port}",),
        connect=(f"tls/localhost:{port}",),
    )
    write_secure_set(spec)
    return Wiring(port, namespace, spec)


class Children:
    """The run's OS processes by name (``router``, the learner id, each actor id), started again under the same name
    after a fault; :meth:`close` kills every one still running, whatever happened. Each child's stderr is appended
    to ``RUN/<name>.log``, each incarnation's stdout goes to ``RUN/<name>.<k>.out``."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.started: dict[str, float] = {}
        """Monotonic start time of each name's current incarnation."""
        self._procs: dict[str, subprocess.Popen[bytes]] = {}
        self._incarnations: dict[str, int] = {}
        self._lock = threading.Lock()  # the RSS sampler reads the processes from its own thread

    def start(self, name: str, argv: list[str], nice: int = 0) -> None:
        k = self._incarnations.get(name, 0) + 1
        with open(self.run_dir / f"{name}.log", "a") as err, open(self.stdout(name, k), "w") as out:
            proc = spawn_child(argv, err, nice=nice, stdout=out)
        with self._lock:
            self._procs[name] = proc
            self._incarnations[name] = k
            self.started[name] = time.monotonic()

    def stdout(self, name: str, k: int | None = None) -> Path:
        return self.run_dir / f"{name}.{k or self._incarnations[name]}.out"

    def running(self) -> dict[str, int]:
        """Name -> pid of every child running now."""
        with self._lock:
            return {name: p.pid for name, p in self._procs.items() if p.poll() is None}

    def signal(self, name: str, sig: int) -> None:
        if self._procs[name].poll() is None:
            self._procs[name].send_signal(sig)

    def kill(self, name: str) -> None:
        self._procs[name].kill()
        self._procs[name].wait()

    def wait(self, name: str, timeout: float) -> int:
        """The exit status of ``name`` within ``timeout`` seconds, SIGKILLed past it (then -9)."""
        try:
            return self._procs[name].wait(timeout)
        except subprocess.TimeoutExpired:
            log.error(
                "%s still running %.0f s after SIGTERM: killed; its log ends:\n%s", name, timeout, self.tail(name)
            )
            self.kill(name)
            return self._procs[name].returncode

    def exited(self) -> list[str]:
        """The children that are not running any more (none should be, between the faults)."""
        with self._lock:
            return [name for name, p in self._procs.items() if p.poll() is not None]

    def tail(self, name: str) -> str:
        return log_tail(self.run_dir / f"{name}.log")

    def close(self) -> None:
        for proc in self._procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)  # a stopped child would not even die before it is continued
                proc.kill()
            proc.wait()


def last_json(path: Path) -> dict[str, Any] | None:
    """The JSON object a ``--json`` process printed last, or None (it printed none: killed, crashed)."""
    lines = path.read_text().strip().splitlines() if path.exists() else []
    try:
        return json.loads(lines[-1]) if lines else None
    except json.JSONDecodeError:
        return None


# -- chaos's own sessions ---------------------------------------------------------------------------------------------

Sighting = tuple[float, Mapping[str, float]]
"""A Status's arrival (monotonic time) and its counters."""


class Observer:
    """Chaos's read-only session (the observer identity): every policy version on the wire in arrival order, and
    the recent Status counters of every sender with their arrival times."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._versions: list[tuple[float, int]] = []
        self._status: dict[str, deque[Sighting]] = {}

    @contextmanager
    def watching(self, conf: zenoh.Config, keys: KeySpace) -> Iterator[None]:
        with ZenohTransport.open(conf, keys) as transport:
            transport.subscribe(keys.policy(), PolicyUpdate, self._on_policy)
            transport.subscribe(keys.status(), Status, self._on_status)
            yield

    def _on_policy(self, msg: PolicyUpdate) -> None:
        with self._lock:
            self._versions.append((time.monotonic(), int(msg.version)))

    def _on_status(self, msg: Status) -> None:
        with self._lock:
            self._status.setdefault(msg.sender, deque(maxlen=STATUS_HISTORY)).append((time.monotonic(), msg.counters))

    def versions(self, after: float = 0.0) -> list[int]:
        with self._lock:
            return [v for t, v in self._versions if t > after]

    def sightings(self, sender: str, after: float) -> list[Sighting]:
        """The Status messages of ``sender`` that arrived after monotonic time ``after``, oldest first."""
        with self._lock:
            return [s for s in self._status.get(sender, ()) if s[0] > after]

    def first(self, sender: str, after: float) -> Sighting | None:
        seen = self.sightings(sender, after)
        return seen[0] if seen else None

    def latest(self, sender: str, after: float = 0.0) -> Sighting | None:
        seen = self.sightings(sender, after)
        return seen[-1] if seen else None


def live_actors(sighting: Sighting) -> int:
    """The learner's count of live actors in one of its Status messages."""
    return int(sighting[1].get("live_actors", 0))


# -- RSS --------------------------------------------------------------------------------------------------------------


class RssSampler:
    """Every ``interval`` seconds the RSS (MB) of every child, logged as one line and kept for the figures."""

    def __init__(self, children: Children, interval: float, t0: float) -> None:
        self.children = children
        self.interval = interval
        self.t0 = t0
        self.samples: list[dict[str, float]] = []
        self.baseline: dict[str, float] = {}
        """RSS when the faults began: the reference of the bound."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="rss", daemon=True)

    def measure(self, names: tuple[str, ...] | None = None) -> dict[str, float]:
        mb: dict[str, float] = {}
        for name, pid in self.children.running().items():
            if names is None or name in names:
                try:
                    mb[name] = round(psutil.Process(pid).memory_info().rss / 2**20, 1)
                except psutil.NoSuchProcess:  # it exited between the listing and the reading
                    continue
        return mb

    def sample(self) -> dict[str, float]:
        mb = self.measure()
        t = round(time.monotonic() - self.t0, 1)
        self.samples.append({"t": t, **mb})
        log.info("t=%.0fs %s", t, ", ".join(f"{name} {value:.0f} MB" for name, value in mb.items()))
        return mb

    def _run(self) -> None:
        while not self._stop.wait(self.interval):
            self.sample()

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
