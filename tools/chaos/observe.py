"""What chaos watches of its cluster (started with :mod:`tools.cluster`'s pieces): chaos's read-only session
(:class:`Observer`), the RSS samples (:class:`RssSampler`), the children's last words, and the waiting for what a
fault expects."""

from __future__ import annotations

import json
import logging
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import psutil
import zenoh

from protocol import KeySpace, PolicyUpdate, Status, ZenohTransport
from tools.cluster import Children

log = logging.getLogger("tools.chaos")  # one name for the package: its lines read "tools.chaos: ..."

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
