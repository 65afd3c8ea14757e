"""``ennc-ql chaos``: the fault suite. A real cluster of OS processes trains while faults are injected; the
reliability contract of docs/protocol.md is then checked from outside and the figures are printed.

The cluster: ``ennc-ql router`` on a free loopback port, and the learner and N actors as its clients (so the router
can be restarted under them). With ``--secure`` (the default) every process has its own certificate, password and
access-control identity (``ennc-ql secure init``'s files, in ``RUN/secure``), and chaos holds one more identity,
``mallory``: authenticated, and played by chaos as a hostile peer. A zenoh session of chaos's own (the ``observer``
identity) records every policy version on the wire and the latest Status of every process.

Once the first policy is checkpointed, one fault every ``--fault-interval`` seconds, in rotation:

=================  ===============================================================================================
learner-kill       SIGKILL the learner just after a checkpoint landed (the most unsaved state); restart ``--resume``
router-restart     SIGKILL the router and start it again on the same port
actor-stop         SIGSTOP an actor for the zenoh lease + 3 s, then SIGCONT: the learner counts it gone, then back
actor-kill         SIGKILL an actor (never actor-0 while there are others) and start a new incarnation of it
poison             seq 0, a batch with NaN rewards at seq 1, then seq 2 on a peer's key: a Reject of 1, an ack of 2
spoof              batches claiming actor-0's id on a peer's own key; secure: puts on actor-0's key itself
unauthenticated    (secure) a session with a valid certificate but no password: refused
wrong-certificate  (secure) a session with the right password but a certificate of another CA: refused
oversize           one 160 MiB put: dropped by zenoh while reassembling it; RSS barely rises, the learner stays up
=================  ===============================================================================================

The rotation always completes one round, past ``--duration`` if need be; after that no fault starts once the
duration is over. Then the actors are stopped (each flushes its outbox and prints its final status), then the
learner (it writes ``RUN/report.json``), then the router, and the contract is checked, each check from figures of
different processes: exactly-once storage, every acknowledged visit in the final tables, policy versions strictly
increasing across restarts, the poisoned stream flowing on, nothing stored from hostile peers, bounded RSS. Exit
status 0 if every check holds, 1 if one fails; ``RUN/chaos.json`` holds what ``--json`` prints. Usage::

    ennc-ql chaos                                       # 120 s, secure, every fault, one every 20 s
    ennc-ql chaos --no-secure --duration 90             # plain TCP (the two TLS faults do not apply)
    ennc-ql chaos --soak 2h --faults learner-kill,router-restart,oversize
    ennc-ql chaos --json --actors 3 --actor-arenas 64 --learner-min-tuples 20000
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import logging
import re
import secrets
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any, Self, TypeVar

import msgpack
import numpy as np
import psutil
import zenoh

from ennc_ql.config import add_config_flags, positive
from ennc_ql.launch import (
    ACTOR_NICENESS,
    SET_BY_UP,
    UP_PRESETS,
    UpConfig,
    child_configs,
    log_tail,
    spawn_child,
    write_configs,
)
from ennc_ql.processes import configure, fail, writable_dir
from ennc_ql.secure import SecureSet, write_secure_set
from ennc_ql.system import free_port
from learner.checkpoint import CHECKPOINT, VersionMark
from protocol import (
    FEATURIZER_DIMS,
    Ack,
    ExperienceBatch,
    KeySpace,
    PolicyUpdate,
    Reject,
    Status,
    ZenohTransport,
    check_id,
    encode,
    zenoh_config,
)
from protocol.security import OBSERVER, ROUTER

log = logging.getLogger(__name__)

FAULTS = (
    "learner-kill",
    "router-restart",
    "actor-stop",
    "actor-kill",
    "poison",
    "spoof",
    "unauthenticated",
    "wrong-certificate",
    "oversize",
)
SECURE_ONLY = frozenset({"unauthenticated", "wrong-certificate"})
"""Faults that test TLS and authentication, which a plain run does not have."""

MALLORY = "mallory"
"""The authenticated identity chaos plays as a hostile peer in a secure run (plain runs use one id per fault)."""

DEFAULT_DURATION_S, DEFAULT_FAULT_INTERVAL_S = 120.0, 20.0
DEFAULT_RSS_INTERVAL_S, SOAK_RSS_INTERVAL_S = 10.0, 60.0
LEARNER_EXTRA_S = 3600.0
"""The learner's own duration is chaos's plus this: chaos ends it by SIGTERM once the actors drained, never the
clock, so every acknowledged message is in its report."""

POISON_TUPLES, INTRUDER_TUPLES, SPOOF_PUTS = 5, 3, 3
"""Tuples per batch of a poison round (two of its three batches are stored: mallory's count is 10 per round, so any
other batch stored under its id shows), tuples of the batch a session that should have been refused puts as mallory,
and lying batches per spoof (each way)."""
OVERSIZE_BYTES = 160 * 2**20
"""Well past zenoh's message size cap (MAX_MESSAGE_BYTES, 64 MiB + 64 KiB, in every configuration of the project)."""
OVERSIZE_RISE_LIMIT_MB = 100.0
"""What the oversize put may add to the learner's or the router's RSS: the cap, not the 160 MiB, bounds it."""
OVERSIZE_SETTLE_S = 4.0
"""RSS is sampled this long after the put returned: the router may still be reassembling then dropping it."""
REFUSAL_TIMEOUT_MS = 3000
"""``connect/timeout_ms`` of a session that should be refused: zenoh.open gives up (ZError) after it."""
RSS_GROWTH_FACTOR, RSS_MARGIN_MB = 2.0, 300.0
"""Bound on each process's RSS over the run: this factor times its RSS when the faults began, plus this margin.
A healthy process of any role stays well within it (its store and queues are bounded); a leak per message, per
reconnect or per restart over a soak does not."""

FIRST_POLICY_TIMEOUT_S = 900.0
"""Phase 1 with the default budget takes minutes on a busy two-core machine."""
RECOVERY_TIMEOUT_S = 120.0
"""Longest wait for a restarted process (the learner loads torch and scikit-learn again) or a reply to a fault."""
ACTOR_STOP_MARGIN_S = 60.0
"""An actor stops after its current trial and its outbox flush (``--actor-flush-timeout``) plus this."""
LEARNER_STOP_S = 600.0
"""The learner's final evaluation (``--learner-final-eval-trials``) and report may take minutes."""
STATUS_SETTLE_S = 1.0
"""After a SIGKILL, a status the dead process had already sent still lands within this."""
STATUS_HISTORY = 512
"""Status messages kept per sender (17 minutes of them at the default 2 s): the faults look back seconds only."""

T = TypeVar("T")


# -- options ----------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ChaosOptions:
    duration: float
    """Seconds from the start of the cluster to the drain."""
    secure: bool
    fault_interval: float
    faults: tuple[str, ...]
    rss_interval: float


def parse_duration(text: str) -> float:
    """Seconds of ``90``, ``90s``, ``30m`` or ``2h``.

    >>> parse_duration("30m"), parse_duration("90s"), parse_duration("2h"), parse_duration("45")
    (1800.0, 90.0, 7200.0, 45.0)
    """
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smh]?)\s*", text)
    if match is None or float(match[1]) <= 0:
        raise ValueError(f"{text!r} is not a duration such as 90s, 30m or 2h")
    return float(match[1]) * {"": 1, "s": 1, "m": 60, "h": 3600}[match[2]]


def parse_faults(text: str | None, secure: bool) -> tuple[str, ...]:
    """The faults named in ``text`` (comma-separated, in that order), or every one that applies."""
    if text is None:
        return tuple(f for f in FAULTS if secure or f not in SECURE_ONLY)
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    for name in names:
        if name not in FAULTS:
            raise ValueError(f"unknown fault {name!r} (valid: {', '.join(FAULTS)})")
        if name in SECURE_ONLY and not secure:
            raise ValueError(f"{name} tests TLS and authentication: it needs --secure")
    if not names:
        raise ValueError("no fault named")
    return names


def chaos_options(args: argparse.Namespace) -> ChaosOptions:
    """The options of ``ennc-ql chaos``, or a one-line error (exit 2) naming the bad value."""
    if args.soak is not None and args.chaos_duration is not None:
        fail("chaos", "give --duration or --soak, not both")
    try:
        duration = parse_duration(args.soak) if args.soak is not None else args.chaos_duration or DEFAULT_DURATION_S
    except ValueError as exc:
        fail("chaos", f"--soak: {exc}")
    try:
        faults = parse_faults(args.faults, args.secure)
    except ValueError as exc:
        fail("chaos", f"--faults: {exc}")
    rss_interval = args.rss_interval or (SOAK_RSS_INTERVAL_S if args.soak is not None else DEFAULT_RSS_INTERVAL_S)
    return ChaosOptions(duration, args.secure, args.fault_interval, faults, rss_interval)


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


class Replies:
    """The learner's Rejects and Acks of one incarnation of a peer's stream."""

    def __init__(self, incarnation: int) -> None:
        self.incarnation = incarnation
        self.rejected: list[int] = []
        self.reasons: list[str] = []
        self.acked = -1
        self._lock = threading.Lock()

    def on_reject(self, msg: Reject) -> None:
        if msg.incarnation == self.incarnation:
            with self._lock:
                self.rejected.append(msg.seq)
                self.reasons.append(msg.reason)

    def on_ack(self, msg: Ack) -> None:
        if msg.incarnation == self.incarnation:
            with self._lock:
                self.acked = max(self.acked, msg.seq)

    def got(self, reject: int, ack: int) -> bool:
        with self._lock:
            return reject in self.rejected and self.acked >= ack


class Peer:
    """A session of chaos's own playing a peer under ``ident``, publishing raw bytes past the publish-side checks."""

    def __init__(self, conf: zenoh.Config, keys: KeySpace, ident: str, dims: int) -> None:
        self.keys = keys
        self.ident = ident
        self.dims = dims
        self.own_key = keys.experience(ident)
        self.transport = ZenohTransport.open(conf, keys)

    def listen(self, replies: Replies) -> None:
        self.transport.subscribe(self.keys.reject(self.ident), Reject, replies.on_reject)
        self.transport.subscribe(self.keys.ack(self.ident), Ack, replies.on_ack)

    def await_learner(self) -> None:
        """Until the learner's subscription reaches this session: what is put before goes nowhere."""
        wait_for("the learner's subscription", RECOVERY_TIMEOUT_S, lambda: self.transport.has_subscribers(self.own_key))

    def batch(self, seq: int, incarnation: int, n: int = POISON_TUPLES, actor_id: str | None = None) -> ExperienceBatch:
        return ExperienceBatch(
            actor_id=actor_id or self.ident,
            incarnation=incarnation,
            seq=seq,
            policy_version=0,
            robot=np.zeros(n, np.int16),
            state=np.zeros((n, self.dims), np.float32),
            action=np.zeros(n, np.uint8),
            reward=np.zeros(n, np.float32),
            next_state=np.zeros((n, self.dims), np.float32),
            done=np.zeros(n, bool),
        )

    def put(self, key: str, payload: bytes) -> None:
        # BLOCK as the protocol's data keys: what is not delivered must be the router's or the learner's doing.
        self.transport.session.put(key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def opens(conf: dict[str, Any]) -> bool:
    """Whether a zenoh session with ``conf`` opens within REFUSAL_TIMEOUT_MS."""
    conf["connect"]["timeout_ms"] = REFUSAL_TIMEOUT_MS
    try:
        with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))):
            return True
    except zenoh.ZError:
        return False


def poisoned(batch: ExperienceBatch) -> bytes:
    """``batch`` on the wire with NaN rewards: its envelope, id and seq readable, its values invalid (docs §5.6)."""
    version, tag, fields = msgpack.unpackb(encode(batch), raw=False)
    fields["reward"][2] = np.full(batch.n_tuples, np.nan, "<f4").tobytes()
    data: bytes = msgpack.packb([version, tag, fields], use_bin_type=True)
    return data


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


# -- the run ----------------------------------------------------------------------------------------------------------


class Chaos:
    """One chaos run: the cluster, the faults in rotation, the drain, the figures. Usage::

    out = Chaos(options, config, run_dir, run_id, namespace).run()   # the JSON object ``--json`` prints
    """

    def __init__(self, options: ChaosOptions, config: UpConfig, run_dir: Path, run_id: str, namespace: str) -> None:
        self.options = options
        self.run_dir = run_dir
        self.run_id = run_id
        self.keys = KeySpace(namespace)
        self.learner, self.actors = child_configs(config)
        self.learner_id = self.learner.learner_id
        self.actor_ids = [a.actor_id for a in self.actors]
        self.dims = FEATURIZER_DIMS[self.learner.featurizer]
        self.wiring = make_wiring(run_dir, namespace, self.learner_id, self.actor_ids, options.secure)
        self.lease_s = int(self.wiring.session(OBSERVER).get_json("transport/link/tx/lease")) / 1000
        self.t0 = time.monotonic()
        self.children = Children(run_dir)
        self.observer = Observer()
        self.rss = RssSampler(self.children, options.rss_interval, self.t0)
        self.records: list[dict[str, Any]] = []
        self.restarts: list[dict[str, Any]] = []
        self.killed: dict[str, list[dict[str, int]]] = {}
        self.spoofed = 0
        self._victims: dict[str, Iterator[str]] = {
            "actor-stop": itertools.cycle(self.actor_ids),
            # actor-0 is never killed while there are others: its exact count proves the spoofed tuples were not stored.
            "actor-kill": itertools.cycle(self.actor_ids[1:] or self.actor_ids),
        }
        self._faults: dict[str, Callable[[], tuple[bool, dict[str, Any]]]] = {
            "learner-kill": self._learner_kill,
            "router-restart": self._router_restart,
            "actor-stop": self._actor_stop,
            "actor-kill": self._actor_kill,
            "poison": self._poison,
            "spoof": self._spoof,
            "unauthenticated": self._unauthenticated,
            "wrong-certificate": self._wrong_certificate,
            "oversize": self._oversize,
        }
        write_configs(config, self.learner, self.actors, run_dir)

    def run(self) -> dict[str, Any]:
        """Start the cluster, apply the faults, drain it and return the figures with the checks; every child is
        killed on the way out, whatever happened (an exception, Ctrl-C)."""
        try:
            self.children.start(ROUTER, ["router", *self.wiring.router_flags()])
            # The observer's zenoh.open would wait for the router forever (clients retry it without end).
            self._wait("the router to listen", RECOVERY_TIMEOUT_S, lambda: listening(self.wiring.port))
            with self.observer.watching(self.wiring.session(OBSERVER), self.keys):
                self.children.start(self.learner_id, self._learner_argv(resume=False))
                for actor in self.actor_ids:
                    self.children.start(actor, self._actor_argv(actor), nice=ACTOR_NICENESS)
                self.rss.start()
                try:
                    self._rotate_faults()
                finally:
                    self.rss.stop()
                finals, codes = self._drain()
        finally:
            self.children.close()
        return self._results(finals, codes)

    def _learner_argv(self, resume: bool) -> list[str]:
        argv = ["learner", "--config", str(self.run_dir / "learner.toml"), "--run-dir", str(self.run_dir), "--json"]
        return [*argv, *self.wiring.client_flags(self.learner_id), *(["--resume"] if resume else [])]

    def _actor_argv(self, actor: str) -> list[str]:
        return ["actor", "--config", str(self.run_dir / f"{actor}.toml"), "--json", *self.wiring.client_flags(actor)]

    def _rotate_faults(self) -> None:
        """Once the first policy is checkpointed, one fault every ``fault_interval`` s in rotation: a whole round at
        least, then until the duration is over; the run then goes on to the end of the duration."""
        if not self._await_first_policy():
            return
        self.rss.baseline = self.rss.sample()
        deadline = self.t0 + self.options.duration
        due = time.monotonic()
        for applied, name in enumerate(itertools.cycle(self.options.faults)):
            if applied >= len(self.options.faults) and max(due, time.monotonic()) >= deadline:
                break
            dead = self.children.exited()
            if dead:  # a fault would only wait for it in vain; the processes check reports it
                log.error(
                    "%s exited: no more faults; the log of %s ends:\n%s", dead, dead[0], self.children.tail(dead[0])
                )
                return
            time.sleep(max(0.0, due - time.monotonic()))
            due = time.monotonic() + self.options.fault_interval
            self.records.append(self._apply(name))
        time.sleep(max(0.0, deadline - time.monotonic()))

    def _await_first_policy(self) -> bool:
        """Until a policy was broadcast and a checkpoint holding it landed (so a killed learner resumes with it)."""
        try:
            self._wait("a first policy", FIRST_POLICY_TIMEOUT_S, lambda: self.observer.versions())
            broadcast = time.time_ns()
            self._wait("a checkpoint of it", RECOVERY_TIMEOUT_S, lambda: self._checkpoint_mtime() > broadcast)
        except WaitTimeout as exc:
            log.error("no fault applied: %s; the learner's log ends:\n%s", exc, self.children.tail(self.learner_id))
            return False
        log.info("first policy v%d checkpointed at t=%.0fs: faults begin", self.observer.versions()[0], self._t())
        return True

    def _t(self) -> float:
        return round(time.monotonic() - self.t0, 1)

    def _wait(self, what: str, timeout: float, probe: Callable[[], T | None]) -> T:
        """:func:`wait_for`, given up at once if a process of the run exited meanwhile (nothing would come)."""

        def probe_alive() -> T | None:
            dead = self.children.exited()
            if dead:
                raise WaitTimeout(f"{', '.join(dead)} exited while chaos waited for {what}")
            return probe()

        return wait_for(what, timeout, probe_alive)

    def _apply(self, name: str) -> dict[str, Any]:
        t = self._t()
        log.info("fault %s at t=%.0fs", name, t)
        try:
            ok, figures = self._faults[name]()
        except (WaitTimeout, zenoh.ZError) as exc:
            ok, figures = False, {"error": str(exc)}
        record = {"name": name, "t_s": t, "ok": ok, **figures}
        (log.info if ok else log.error)("fault %s %s: %s", name, "held" if ok else "FAILED", json.dumps(figures))
        return record

    # -- the faults (each returns whether what it expects held, and its figures) ------------------------------------

    def _learner_kill(self) -> tuple[bool, dict[str, Any]]:
        landed = self._checkpoint_mtime()
        self._wait("the next checkpoint", RECOVERY_TIMEOUT_S, lambda: self._checkpoint_mtime() != landed)
        self.children.kill(self.learner_id)  # at once: the moment with the most state not in any checkpoint
        killed = time.monotonic()
        before = VersionMark(self.run_dir).load()
        starts = len(self._started_versions())
        self.children.start(self.learner_id, self._learner_argv(resume=True))
        logged = self._wait(
            "the resumed learner to start", RECOVERY_TIMEOUT_S, lambda: self._started_versions()[starts:]
        )
        arrived, _ = self._wait(
            "a status of the resumed learner", RECOVERY_TIMEOUT_S, lambda: self._learner_since(killed)
        )
        seen = self._wait("a policy of the resumed learner", RECOVERY_TIMEOUT_S, lambda: self.observer.versions(killed))
        figures = {
            "published_before": before,
            "first_version_logged": logged[0],
            "first_version_seen": seen[0],
            "recovered_s": round(arrived - killed, 1),
        }
        self.restarts.append(figures)
        return logged[0] > before and seen[0] > before, figures

    def _started_versions(self) -> list[int]:
        """The version each learner incarnation announced as it started, from its log."""
        text = (self.run_dir / f"{self.learner_id}.log").read_text(errors="replace")
        return [int(v) for v in re.findall(r"started \(policy version (\d+)\)", text)]

    def _checkpoint_mtime(self) -> int:
        path = self.run_dir / CHECKPOINT
        return path.stat().st_mtime_ns if path.exists() else 0

    def _learner_since(self, t: float) -> Sighting | None:
        return self.observer.first(self.learner_id, t)

    def _router_restart(self) -> tuple[bool, dict[str, Any]]:
        self.children.kill(ROUTER)
        down = time.monotonic()
        self.children.start(ROUTER, ["router", *self.wiring.router_flags()])
        back: dict[str, float] = {}
        for sender in (self.learner_id, *self.actor_ids):
            what = f"a status of {sender} through the new router"
            arrived, _ = self._wait(what, RECOVERY_TIMEOUT_S, partial(self.observer.first, sender, down))
            back[sender] = round(arrived - down, 1)
        return True, {"recovered_s": back[self.learner_id], "status_back_s": back}

    def _actor_stop(self) -> tuple[bool, dict[str, Any]]:
        actor = next(self._victims["actor-stop"])
        pause = self.lease_s + 3.0
        n = len(self.actor_ids)

        def live(after: float, below: bool) -> Sighting | None:
            return next(
                (s for s in self.observer.sightings(self.learner_id, after) if (live_actors(s) < n) == below), None
            )

        # From a full house (an earlier fault may still be settling), so the drop seen next is this stop's.
        self._wait("the learner to count every actor live", RECOVERY_TIMEOUT_S, partial(live, time.monotonic(), False))
        self.children.signal(actor, signal.SIGSTOP)
        stopped = time.monotonic()
        try:
            time.sleep(pause)  # past the lease: the router drops the session and its liveliness token goes
        finally:
            self.children.signal(actor, signal.SIGCONT)
        resumed = time.monotonic()
        dropped = self._wait(
            f"the learner to count {actor} gone", RECOVERY_TIMEOUT_S, lambda: live(stopped, below=True)
        )
        back = self._wait(
            f"the learner to count {actor} back", RECOVERY_TIMEOUT_S, lambda: live(dropped[0], below=False)
        )
        figures = {
            "actor": actor,
            "stopped_s": pause,
            "live_actors_min": min(live_actors(s) for s in self.observer.sightings(self.learner_id, stopped)),
            "gone_after_s": round(dropped[0] - stopped, 1),
            "recovered_s": round(back[0] - resumed, 1),
        }
        return back[0] > resumed, figures  # counted back while still stopped: it never left

    def _actor_kill(self) -> tuple[bool, dict[str, Any]]:
        actor = next(self._victims["actor-kill"])
        born = self.children.started[actor]
        self.children.kill(actor)
        time.sleep(STATUS_SETTLE_S)
        # Its last status: lower bounds of what it had sent and had acknowledged (its outbox is lost by design).
        last = self.observer.latest(actor, born)
        counters = {k: int(last[1].get(k, 0)) if last else 0 for k in ("tuples_sent", "tuples_acked", "visits_acked")}
        self.killed.setdefault(actor, []).append(counters)
        restarted = time.monotonic()
        self.children.start(actor, self._actor_argv(actor), nice=ACTOR_NICENESS)
        what = f"a status of the new incarnation of {actor}"
        arrived, _ = self._wait(what, RECOVERY_TIMEOUT_S, lambda: self.observer.first(actor, restarted))
        return True, {"actor": actor, "last_seen": counters, "recovered_s": round(arrived - restarted, 1)}

    def _poison(self) -> tuple[bool, dict[str, Any]]:
        ident = self.wiring.hostile("poisoner")
        replies = Replies(secrets.randbits(64))  # a new incarnation per round: its seqs start at 0 again
        with Peer(self.wiring.session(ident), self.keys, ident, self.dims) as peer:
            peer.listen(replies)
            peer.await_learner()
            peer.put(peer.own_key, encode(peer.batch(0, replies.incarnation)))
            peer.put(peer.own_key, poisoned(peer.batch(1, replies.incarnation)))
            peer.put(peer.own_key, encode(peer.batch(2, replies.incarnation)))
            sent = time.monotonic()
            self._wait("the Reject of seq 1 and an ack of seq 2", RECOVERY_TIMEOUT_S, lambda: replies.got(1, 2))
        figures = {
            "peer": ident,
            "incarnation": f"{replies.incarnation:x}",
            "rejected_seqs": replies.rejected,
            "reason": replies.reasons[0],
            "acked_seq": replies.acked,
            "recovered_s": since(sent),
        }
        return replies.rejected == [1], figures

    def _spoof(self) -> tuple[bool, dict[str, Any]]:
        ident, target = self.wiring.hostile("spoofer"), self.actor_ids[0]
        last = self.observer.latest(self.learner_id)
        before = int(last[1].get("rejected", 0)) if last else 0
        incarnation = secrets.randbits(64)
        with Peer(self.wiring.session(ident), self.keys, ident, self.dims) as peer:
            peer.await_learner()
            for seq in range(SPOOF_PUTS):  # the learner must count these as IdentityMismatch and drop them
                peer.put(peer.own_key, encode(peer.batch(seq, incarnation, actor_id=target)))
            # On the genuine actor's key itself: the router's access control must drop them before the learner.
            on_target = SPOOF_PUTS if self.options.secure else 0
            for seq in range(on_target):
                peer.put(self.keys.experience(target), encode(peer.batch(seq, incarnation, actor_id=target)))
        sent = time.monotonic()
        self.spoofed += SPOOF_PUTS

        def counted() -> int | None:
            seen = self.observer.latest(self.learner_id, sent)
            rise = int(seen[1].get("rejected", 0)) - before if seen else 0
            return rise if rise >= SPOOF_PUTS else None

        rise = self._wait("the learner to count the lies", RECOVERY_TIMEOUT_S, counted)
        figures = {"peer": ident, "claimed": target, "lies_on_own_key": SPOOF_PUTS, "puts_on_claimed_key": on_target}
        return True, {**figures, "learner_rejected_rise": rise, "recovered_s": since(sent)}

    def _unauthenticated(self) -> tuple[bool, dict[str, Any]]:
        conf = self.wiring.client_dict(MALLORY)
        del conf["transport"]["auth"]  # a valid certificate, no password
        return self._refused(conf)

    def _wrong_certificate(self) -> tuple[bool, dict[str, Any]]:
        with tempfile.TemporaryDirectory(prefix="chaos-other-ca-") as other:
            assert self.wiring.secure is not None
            foreign = dataclasses.replace(self.wiring.secure, folder=Path(other), actor_ids=(MALLORY,))
            write_secure_set(foreign)  # another CA, and a mallory certificate signed by it
            conf = self.wiring.client_dict(MALLORY)  # the genuine password: only the certificate is wrong
            tls = conf["transport"]["link"]["tls"]
            tls["connect_certificate"], tls["connect_private_key"] = (
                str(foreign.folder / f"{MALLORY}.pem"),
                str(foreign.folder / f"{MALLORY}.key"),
            )
            return self._refused(conf)

    def _refused(self, conf: dict[str, Any]) -> tuple[bool, dict[str, Any]]:
        """Whether a session with ``conf`` is refused. One that opens puts a batch where the genuine mallory may,
        and the checks find it if it was stored. The genuine mallory connects first: a refusal below is then the
        router's judgement, not an outage (the fault holds only if it did)."""
        control = opens(self.wiring.client_dict(MALLORY))
        conf["connect"]["timeout_ms"] = REFUSAL_TIMEOUT_MS
        started = time.monotonic()
        try:
            with Peer(zenoh.Config.from_json5(json.dumps(conf)), self.keys, MALLORY, self.dims) as peer:
                peer.put(peer.own_key, encode(peer.batch(0, secrets.randbits(64), n=INTRUDER_TUPLES)))
                time.sleep(STATUS_SETTLE_S)
        except zenoh.ZError as exc:
            error = str(exc).split(" at ")[0]  # zenoh appends the Rust source location
            return control, {"refused": True, "control_opened": control, "error": error, "refused_s": since(started)}
        log.warning("a session that should have been refused opened; it put %d tuples as mallory", INTRUDER_TUPLES)
        return control, {"refused": False, "control_opened": control}

    def _oversize(self) -> tuple[bool, dict[str, Any]]:
        ident = self.wiring.hostile("oversizer")
        watched = (ROUTER, self.learner_id)
        before = self.rss.measure(watched)
        with Peer(self.wiring.session(ident), self.keys, ident, self.dims) as peer:
            peer.await_learner()
            peak, put_s = self._peak_rss_while(watched, lambda: peer.put(peer.own_key, bytes(OVERSIZE_BYTES)))
        after = time.monotonic()
        arrived, _ = self._wait(
            "a learner status after the oversize put", RECOVERY_TIMEOUT_S, lambda: self._learner_since(after)
        )
        rise = {name: round(peak.get(name, 0.0) - before.get(name, 0.0), 1) for name in watched}
        up = self.learner_id in self.children.running()
        figures = {
            "peer": ident,
            "bytes": OVERSIZE_BYTES,
            "put_s": put_s,
            "rss_before_mb": before,
            "rss_peak_mb": peak,
            "rss_rise_mb": rise,
            "learner_up": up,
            "recovered_s": round(arrived - after, 1),
        }
        return up and all(r < OVERSIZE_RISE_LIMIT_MB for r in rise.values()), figures

    def _peak_rss_while(self, names: tuple[str, ...], action: Callable[[], None]) -> tuple[dict[str, float], float]:
        """Run ``action`` on a thread, sampling ``names``' RSS every 0.25 s until OVERSIZE_SETTLE_S after it ended:
        the peaks, and how long it took."""
        errors: list[zenoh.ZError] = []

        def act() -> None:
            try:
                action()
            except zenoh.ZError as exc:
                errors.append(exc)

        worker = threading.Thread(target=act, name="oversize-put", daemon=True)
        started, peak = time.monotonic(), self.rss.measure(names)
        worker.start()
        ended: float | None = None
        while ended is None or time.monotonic() - ended < OVERSIZE_SETTLE_S:
            time.sleep(0.25)
            for name, mb in self.rss.measure(names).items():
                peak[name] = max(peak.get(name, 0.0), mb)
            if ended is None and not worker.is_alive():
                ended = time.monotonic()
            if ended is None and time.monotonic() - started > RECOVERY_TIMEOUT_S:
                raise WaitTimeout(f"the {OVERSIZE_BYTES} B put still blocked after {RECOVERY_TIMEOUT_S:.0f} s")
        if errors:
            raise errors[0]
        return peak, round(ended - started, 1)

    # -- the end ----------------------------------------------------------------------------------------------------

    def _drain(self) -> tuple[dict[str, dict[str, Any] | None], dict[str, Any]]:
        """Stop the actors (each flushes its outbox and prints its final status), then the learner (it writes its
        report), then the router; the actors' final statuses, and how every process ended."""
        running = self.children.running()
        ended: dict[str, Any] = {
            name: {"running": name in running} for name in (ROUTER, self.learner_id, *self.actor_ids)
        }
        for actor in self.actor_ids:
            self.children.signal(actor, signal.SIGTERM)
        finals: dict[str, dict[str, Any] | None] = {}
        for actor in self.actor_ids:
            ended[actor]["code"] = self.children.wait(actor, self.actors[0].flush_timeout + ACTOR_STOP_MARGIN_S)
            finals[actor] = last_json(self.children.stdout(actor))
        for name, grace in ((self.learner_id, LEARNER_STOP_S), (ROUTER, 10.0)):
            self.children.signal(name, signal.SIGTERM)
            ended[name]["code"] = self.children.wait(name, grace)
        return finals, ended

    def _results(self, finals: dict[str, dict[str, Any] | None], ended: dict[str, Any]) -> dict[str, Any]:
        report_path = self.run_dir / "report.json"
        report = json.loads(report_path.read_text()) if report_path.exists() else None
        evidence = Evidence(
            actor_ids=self.actor_ids,
            report=report,
            finals=finals,
            killed=self.killed,
            versions=self.observer.versions(),
            restarts=self.restarts,
            poison_id=self.wiring.hostile("poisoner"),
            spoofed=self.spoofed,
            records=self.records,
            requested=self.options.faults,
            rss_samples=self.rss.samples,
            rss_baseline=self.rss.baseline,
            ended=ended,
        )
        return figures_and_checks(evidence, self._summary())

    def _summary(self) -> dict[str, Any]:
        return {
            "run_id": self.run_id,
            "run_dir": str(self.run_dir),
            "secure": self.options.secure,
            "namespace": self.keys.namespace,
            "endpoint": self.wiring.endpoint,
            "actors": len(self.actor_ids),
            "duration_s": self.options.duration,
            "fault_interval_s": self.options.fault_interval,
            "wall_s": self._t(),
            "rss_interval_s": self.options.rss_interval,
        }


def last_json(path: Path) -> dict[str, Any] | None:
    """The JSON object a ``--json`` process printed last, or None (it printed none: killed, crashed)."""
    lines = path.read_text().strip().splitlines() if path.exists() else []
    try:
        return json.loads(lines[-1]) if lines else None
    except json.JSONDecodeError:
        return None


# -- the checks -------------------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Evidence:
    """What the checks read, each figure from the process that produced it."""

    actor_ids: list[str]
    report: dict[str, Any] | None
    """The learner's report.json (None: it wrote none)."""
    finals: dict[str, dict[str, Any] | None]
    """Each actor's final status, as its last incarnation printed it."""
    killed: dict[str, list[dict[str, int]]]
    """Each killed incarnation's last status, as chaos's observer saw it."""
    versions: list[int]
    """Policy versions in the order they arrived at chaos's observer."""
    restarts: list[dict[str, Any]]
    """Each learner-kill: versions published before it, the first after it (logged and seen)."""
    poison_id: str
    spoofed: int
    """Batches sent on a peer's own key claiming another actor's id."""
    records: list[dict[str, Any]]
    requested: tuple[str, ...]
    rss_samples: list[dict[str, float]]
    rss_baseline: dict[str, float]
    ended: dict[str, Any]
    """Each process: whether it was still running at the end, and its exit status after SIGTERM."""


@dataclass(frozen=True, slots=True)
class Check:
    name: str
    ok: bool
    detail: str


def actor_figures(ev: Evidence) -> dict[str, dict[str, Any]]:
    """Per actor id: tuples stored (the learner), sent, acknowledged and held (its last incarnation), and the last
    seen acknowledged figures of its killed incarnations (the observer)."""
    stored = (ev.report or {}).get("tuples_by_actor", {})
    figures: dict[str, dict[str, Any]] = {}
    for actor in ev.actor_ids:
        final = ev.finals.get(actor) or {}
        killed = ev.killed.get(actor, [])
        figures[actor] = {
            "stored": stored.get(actor, 0),
            **{k: final.get(k) for k in ("tuples_sent", "tuples_acked", "visits_acked")},
            "held": final.get("outbox"),
            **{k: final.get(k) for k in ("resent", "rejected", "policy_version")},
            "killed_incarnations": len(killed),
            "killed_tuples_acked": sum(k["tuples_acked"] for k in killed),
            "killed_visits_acked": sum(k["visits_acked"] for k in killed),
        }
    return figures


def check_exactly_once(ev: Evidence, actors: dict[str, dict[str, Any]]) -> Check:
    name = "exactly once"
    if ev.report is None:
        return Check(name, False, "no learner report")
    problems = []
    for actor, a in actors.items():
        sent, acked, stored = a["tuples_sent"], a["tuples_acked"], a["stored"]
        if sent is None:
            problems.append(f"{actor}: no final status")
            continue
        if a["held"] != 0 or acked != sent:
            problems.append(f"{actor}: {acked} of {sent} tuples acknowledged, {a['held']} messages held")
        if a["killed_incarnations"]:
            floor = sent + a["killed_tuples_acked"]
            if stored < floor:
                problems.append(f"{actor}: {stored} stored < {floor} (sent by its last incarnation + acked to killed)")
        elif stored != sent:
            problems.append(f"{actor}: {stored} stored != {sent} sent")
    if ev.report["gaps"]:
        problems.append(f"{ev.report['gaps']} gaps")
    done = f"every tuple stored once (0 gaps, {ev.report['duplicates']} re-sent duplicates dropped)"
    return Check(name, not problems, "; ".join(problems) or done)


def visit_figures(ev: Evidence, actors: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Visits in the final policy file's tables (the learner) against those acknowledged to the actors."""
    from algorithm.policy_file import PolicyFileError, load_policy

    figures: dict[str, Any] = {
        "acked": sum(a["visits_acked"] or 0 for a in actors.values()),
        "killed_acked": sum(a["killed_visits_acked"] for a in actors.values()),
        "in_tables": None,
    }
    path = (ev.report or {}).get("policy_file")
    if path:
        try:
            policy, _ = load_policy(path)
        except (OSError, PolicyFileError) as exc:
            log.error("cannot read the final policy %s: %s", path, exc)
        else:
            figures["in_tables"] = 0 if policy.visits is None else int(policy.visits.astype(np.int64).sum())
    return figures


def check_visits(ev: Evidence, visits: dict[str, Any]) -> Check:
    name = "acknowledged visits kept"
    in_tables, acked, killed = visits["in_tables"], visits["acked"], visits["killed_acked"]
    if in_tables is None:
        return Check(name, False, "no readable final policy file")
    if ev.killed:  # a killed incarnation's last acknowledgements were never seen: a lower bound only
        ok, relation = in_tables >= acked + killed, f">= {acked} + {killed} acked to killed incarnations"
    else:
        ok, relation = in_tables == acked, f"== {acked} acknowledged"
    return Check(name, ok and acked > 0, f"{in_tables} visits in the final tables {relation}")


def check_versions(ev: Evidence) -> Check:
    seen = ev.versions
    increasing = all(b > a for a, b in itertools.pairwise(seen))
    jumps = [
        f"{r['published_before']} -> {r['first_version_logged']} (seen {r['first_version_seen']})" for r in ev.restarts
    ]
    after = all(min(r["first_version_logged"], r["first_version_seen"]) > r["published_before"] for r in ev.restarts)
    shown = f"{len(seen)} seen, v{seen[0]}..v{seen[-1]}" if seen else "none seen"
    detail = f"{shown}, {'strictly increasing' if increasing else 'NOT strictly increasing'}"
    if jumps:
        detail += f"; published before a kill -> first after: {', '.join(jumps)}"
    return Check("policy versions", bool(seen) and increasing and after, detail)


def check_poison(ev: Evidence) -> Check | None:
    rounds = [r for r in ev.records if r["name"] == "poison"]
    if not rounds:
        return None
    flowed = sum(r.get("rejected_seqs") == [1] and r.get("acked_seq", -1) >= 2 for r in rounds)
    stored = (ev.report or {}).get("tuples_by_actor", {}).get(ev.poison_id, 0)
    expected = 2 * POISON_TUPLES * len(rounds)
    detail = (
        f"{flowed} of {len(rounds)} rounds: Reject of seq 1 and ack of seq 2; "
        f"{stored} tuples stored for {ev.poison_id} (expected {expected})"
    )
    return Check("poisoned stream flows on", flowed == len(rounds) and stored == expected, detail)


def check_hostile(ev: Evidence) -> Check | None:
    refusals = [r for r in ev.records if r["name"] in SECURE_ONLY]
    if not refusals and not ev.spoofed and not any(r["name"] == "oversize" for r in ev.records):
        return None
    if ev.report is None:
        return Check("nothing from hostile peers", False, "no learner report")
    report = ev.report
    allowed = set(ev.actor_ids) | ({ev.poison_id} if any(r["name"] == "poison" for r in ev.records) else set())
    strangers = {k: v for k, v in report.get("tuples_by_actor", {}).items() if k not in allowed}
    lies = report.get("rejected_by_type", {}).get("IdentityMismatch", 0)
    problems = [f"stored from {who}: {n} tuples" for who, n in strangers.items()]
    if lies != ev.spoofed:
        problems.append(f"{lies} IdentityMismatch rejections for {ev.spoofed} lies")
    refused = sum(bool(r.get("refused")) for r in refusals)  # one that opened is caught above if it stored anything
    done = f"0 tuples stored from them, {lies} lies rejected" + (
        f", {refused} of {len(refusals)} sessions refused" if refusals else ""
    )
    return Check("nothing from hostile peers", not problems, "; ".join(problems) or done)


def rss_bounds(ev: Evidence) -> dict[str, float]:
    return {name: round(RSS_GROWTH_FACTOR * mb + RSS_MARGIN_MB) for name, mb in ev.rss_baseline.items()}


def check_rss(ev: Evidence, peaks: dict[str, float]) -> Check:
    bounds = rss_bounds(ev)
    problems = [f"{n} {peaks[n]:.0f} MB > {bound:.0f} MB" for n, bound in bounds.items() if peaks.get(n, 0) > bound]
    for r in ev.records:
        if r["name"] == "oversize":
            big = {n: mb for n, mb in r.get("rss_rise_mb", {}).items() if mb >= OVERSIZE_RISE_LIMIT_MB}
            problems += [f"{n} rose {mb:.0f} MB on the oversize put at t={r['t_s']:.0f}s" for n, mb in big.items()]
    if not bounds:
        problems.append("no RSS baseline (the faults never began)")
    shown = ", ".join(f"{n} {mb:.0f}" for n, mb in peaks.items())
    return Check("RSS bounded", not problems, "; ".join(problems) or f"max MB: {shown}")


def check_faults(ev: Evidence) -> Check:
    applied = {r["name"] for r in ev.records}
    problems = [f"{name} never applied" for name in ev.requested if name not in applied]
    problems += [
        f"{r['name']} at t={r['t_s']:.0f}s: {r.get('error', 'not as expected')}" for r in ev.records if not r["ok"]
    ]
    done = f"{len(ev.records)} applied ({', '.join(dict.fromkeys(r['name'] for r in ev.records))}), every one held"
    return Check("faults held", not problems, "; ".join(problems) or done)


def check_processes(ev: Evidence) -> Check:
    problems = [
        f"{name} {'had exited before the end' if not e['running'] else 'exited with status ' + str(e.get('code'))}"
        for name, e in ev.ended.items()
        if not e["running"] or e.get("code") != 0
    ]
    return Check("processes", not problems, "; ".join(problems) or "every process ran to the end and exited 0")


def figures_and_checks(ev: Evidence, summary: dict[str, Any]) -> dict[str, Any]:
    """The JSON object of a run: its figures and every check of the contract."""
    actors = actor_figures(ev)
    visits = visit_figures(ev, actors)
    peaks = max_rss(ev.rss_samples)
    checks = [
        check_faults(ev),
        check_processes(ev),
        check_exactly_once(ev, actors),
        check_visits(ev, visits),
        check_versions(ev),
        check_poison(ev),
        check_hostile(ev),
        check_rss(ev, peaks),
    ]
    held = [c for c in checks if c is not None]
    report = ev.report or {}
    learner_keys = (
        *("tuples_received", "tuples_by_actor", "duplicates", "gaps", "rejected", "rejected_by_type"),
        *("stale_increments", "policy_version", "final_coverage_mean", "policy_file"),
    )
    return {
        **summary,
        "passed": all(c.ok for c in held),
        "failed": [c.name for c in held if not c.ok],
        "checks": [dataclasses.asdict(c) for c in held],
        "faults": ev.records,
        "actors": actors,
        "visits": visits,
        "versions": {"seen": ev.versions, "restarts": ev.restarts},
        "learner": {k: report.get(k) for k in learner_keys},
        "processes": ev.ended,
        "rss": {"samples": ev.rss_samples, "baseline_mb": ev.rss_baseline, "max_mb": peaks, "bound_mb": rss_bounds(ev)},
    }


def max_rss(samples: list[dict[str, float]]) -> dict[str, float]:
    peaks: dict[str, float] = {}
    for sample in samples:
        for name, mb in sample.items():
            if name != "t":
                peaks[name] = max(peaks.get(name, 0.0), mb)
    return peaks


# -- the command ------------------------------------------------------------------------------------------------------


def _fault_line(record: dict[str, Any]) -> str:
    shown = {k: v for k, v in record.items() if k not in ("name", "t_s", "ok")}
    figures = ", ".join(f"{k} {v if isinstance(v, str | int | float) else json.dumps(v)}" for k, v in shown.items())
    return f"  t={record['t_s']:>5.0f}s  {record['name']:<17} {'held' if record['ok'] else 'FAILED':<6}  {figures}"


def results_table(out: dict[str, Any]) -> str:
    verdict = "PASSED" if out["passed"] else f"FAILED ({', '.join(out['failed'])})"
    mode = "secure" if out["secure"] else "plain"
    lines = [f"chaos {out['run_id']} ({mode}, {len(out['faults'])} faults in {out['wall_s']:.0f} s): {verdict}"]
    lines += [f"  {'PASS' if c['ok'] else 'FAIL'}  {c['name']:<26} {c['detail']}" for c in out["checks"]]
    lines += ["", f"  {'actor':<12}{'stored':>10}{'sent':>10}{'acked':>10}{'visits acked':>14}{'held':>6}  killed"]
    for actor, a in out["actors"].items():
        killed = f"{a['killed_incarnations']} (acked {a['killed_tuples_acked']})" if a["killed_incarnations"] else "-"
        lines.append(
            f"  {actor:<12}{a['stored']:>10}{a['tuples_sent']!s:>10}{a['tuples_acked']!s:>10}"
            f"{a['visits_acked']!s:>14}{a['held']!s:>6}  {killed}"
        )
    lines += ["", "faults", *map(_fault_line, out["faults"])]
    rejected = out["learner"]["rejected_by_type"] or {}
    lines += ["", f"rejected by class: {', '.join(f'{k} {v}' for k, v in rejected.items()) or 'none'}"]
    lines.append(f"RSS max (MB): {', '.join(f'{k} {v:.0f}' for k, v in out['rss']['max_mb'].items())}")
    lines.append(f"figures: {out['run_dir']}/chaos.json")
    return "\n".join(lines)


def _interrupted(signum: int, _frame: FrameType | None) -> None:
    # SIGTERM as Ctrl-C: the run's `finally` then kills every child instead of leaving them behind.
    raise KeyboardInterrupt(signal.Signals(signum).name)


def cmd_chaos(args: argparse.Namespace) -> int:
    options = chaos_options(args)
    config: UpConfig = configure(UpConfig, args, "chaos", defaults=UP_PRESETS)
    config = dataclasses.replace(config, duration=options.duration + LEARNER_EXTRA_S)
    run_id = args.run_id or time.strftime("chaos-%Y%m%d-%H%M%S")
    try:
        check_id(run_id, "--run-id")
        namespace = check_id(f"chaos-{run_id}", "--run-id (in the namespace chaos-<id>)")
    except ValueError as exc:
        fail("chaos", str(exc))
    if (args.runs / run_id).exists() and any((args.runs / run_id).iterdir()):
        # A report or checkpoint left there by another run would be taken for this one's.
        fail("chaos", f"--run-id {run_id}: {args.runs / run_id} is not empty; choose another run id")
    run_dir = writable_dir(args.runs / run_id, "chaos", "--runs")
    signal.signal(signal.SIGTERM, _interrupted)
    try:
        out = Chaos(options, config, run_dir, run_id, namespace).run()
    except KeyboardInterrupt:
        print("ennc-ql chaos: interrupted; every child process was killed", file=sys.stderr)
        return 130
    except WaitTimeout as exc:
        print(f"ennc-ql chaos: the cluster did not start: {exc}; see the logs in {run_dir}", file=sys.stderr)
        return 1
    (run_dir / "chaos.json").write_text(json.dumps(out, indent=2))
    print(json.dumps(out) if args.json else results_table(out))
    return 0 if out["passed"] else 1


def add_chaos_parser(sub: Any) -> None:
    p = sub.add_parser(
        "chaos",
        help="the fault suite: a real cluster trains under injected faults, then the reliability contract is checked",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument(
        "--duration",
        dest="chaos_duration",
        type=positive(float),
        metavar="SECONDS",
        help=f"run length from the cluster's start (default {DEFAULT_DURATION_S:.0f}; one round of faults at least)",
    )
    p.add_argument(
        "--soak",
        metavar="DURATION",
        help=f"a long run, e.g. 90s, 30m, 2h (sets the duration; RSS every {SOAK_RSS_INTERVAL_S:.0f} s)",
    )
    p.add_argument(
        "--secure",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="TLS, passwords and access control, with the TLS faults (default: on)",
    )
    p.add_argument(
        "--fault-interval",
        type=positive(float),
        default=DEFAULT_FAULT_INTERVAL_S,
        metavar="SECONDS",
        help=f"seconds between fault starts (default {DEFAULT_FAULT_INTERVAL_S:.0f})",
    )
    p.add_argument("--faults", metavar="NAME,...", help=f"faults in rotation (default all: {', '.join(FAULTS)})")
    p.add_argument(
        "--rss-interval",
        type=positive(float),
        metavar="SECONDS",
        help="seconds between RSS samples "
        f"(default {DEFAULT_RSS_INTERVAL_S:.0f}, {SOAK_RSS_INTERVAL_S:.0f} with --soak)",
    )
    p.add_argument("--runs", type=Path, default=Path("runs"), help="parent folder of the run folder (default runs/)")
    p.add_argument("--run-id", help="run folder name (default chaos-<timestamp>)")
    p.add_argument("--config", metavar="FILE", help="TOML file of the cluster's configuration (e.g. a run's up.toml)")
    p.add_argument("--json", action="store_true", help="print the figures and checks as one JSON object")
    add_config_flags(
        p.add_argument_group("cluster configuration (ennc_ql.launch.UpConfig)"),
        UpConfig,
        exclude=(*SET_BY_UP, "duration"),
        defaults=UP_PRESETS,
    )
    p.set_defaults(func=cmd_chaos)
