"""``ennc-ql bench transport``: experience tuples/s from K actor processes into the learner's store over Zenoh.

Two phases in one run, with the same K publisher processes, payload size and zenoh configuration (loopback, BLOCK
congestion control, reliable):

1. **protocol**: each publisher builds an :class:`~protocol.ExperienceBatch` per sequence number (d = 6) and
   publishes it through :class:`~protocol.ZenohTransport` (validation + msgpack codec), as an actor does; the
   receiver is the learner's real receive path, :class:`learner.intake.ExperienceIntake` behind a ZenohTransport
   subscription (decode, validate, de-duplicate by (actor, incarnation, seq), keep in the bounded store).
2. **raw zenoh**: the publishers ``put`` one pre-built byte string of the same size in a loop; a plain subscriber
   only counts.

``tuples_per_s`` is the stored tuples over the time from the start command to the last store; ``ratio`` =
protocol / raw; ``lost`` = batches the publishers sent − batches the ledger accepted. Usage::

    out = bench_transport(actors=2, batch_size=16384, seconds=3.0)
    out["tuples_per_s"], out["ratio"], out["lost"]

Zenoh's shared-memory transport is off by default here: the figure stands for actors on other machines, where it
cannot apply. On one host zenoh would hand the raw payloads over through shared memory at memory speed (measured
6-11 GB/s, 25-50 k payloads of 230 kB per second), a baseline that no path which decodes, validates and copies
each batch comes near; ``shared_memory=True`` measures that case.

The publishers are :mod:`tools.bench.publisher` subprocesses driven through their stdin; the parent starts each
phase in all of them at once. Their batches are stamped with the paper's formulation (collab6d, d = 6), the state
every figure of this benchmark was measured with.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from learner.intake import ExperienceIntake
from protocol import DEFAULT_KEYS, ExperienceBatch, ZenohTransport, encode
from protocol.security import ROUTER
from sim.formulation import FORMULATIONS
from tools.bench.publisher import RAW_KEY, STARTUP_TIMEOUT_S, bench_zenoh_config, template_batch
from tools.progress import ProgressBar
from tools.secure import SecureSet, write_secure_set
from tools.system import free_port

FORMULATION = FORMULATIONS["paper"]
"""What the batches are stamped with and the receiver stores: collab6d (d = 6), as in every figure measured so far."""
DIM = FORMULATION.dim
STORE_CAPACITY = 1 << 20
"""Tuples the receiver's store keeps (the learner's default is of the same order)."""
TARGET = {"tuples_per_s": 5e6, "ratio": 0.5, "lost": 0}
_DRAIN_TIMEOUT_S = 30.0


class _Publishers:
    """The K publisher subprocesses and their command channel."""

    def __init__(self, procs: list[subprocess.Popen[str]]) -> None:
        self.procs = procs

    @staticmethod
    def _answer(proc: subprocess.Popen[str], timeout: float, expected: str) -> str:
        assert proc.stdout is not None
        stdout = proc.stdout
        lines: list[str] = []
        # readline has no timeout; a reader thread gives one (it ends at EOF once the process is gone).
        reader = threading.Thread(target=lambda: lines.append(stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        answer = lines[0].strip() if lines else ""
        if not answer.startswith(expected):
            raise RuntimeError(f"bench publisher {proc.pid} answered {answer!r}, expected {expected!r}")
        return answer

    def wait_ready(self) -> None:
        for proc in self.procs:
            self._answer(proc, STARTUP_TIMEOUT_S, "ready")

    def run_phase(self, phase: str, seconds: float) -> tuple[int, float]:
        """Start ``phase`` in every publisher at once; the batches they sent and the CPU seconds they used, in all."""
        for proc in self.procs:
            assert proc.stdin is not None
            proc.stdin.write(f"{phase} {seconds}\n")
            proc.stdin.flush()
        answers = [self._answer(p, seconds + _DRAIN_TIMEOUT_S, "sent ").split() for p in self.procs]
        return sum(int(a[1]) for a in answers), sum(float(a[2]) for a in answers)


@contextmanager
def _publishers(
    endpoint: str, actors: int, batch_size: int, shared_memory: bool, secure: SecureSet | None
) -> Iterator[_Publishers]:
    procs: list[subprocess.Popen[str]] = []
    shm_flag = "--shared-memory" if shared_memory else "--no-shared-memory"
    stamp = list(FORMULATION.names)
    try:
        for i in range(actors):
            argv = [endpoint, f"bench-{i}", str(batch_size), "--stamp", *stamp, "--dim", str(DIM), shm_flag]
            if secure is not None:
                argv += ["--zenoh-config", str(secure.config(f"bench-{i}"))]
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "tools.bench.publisher", *argv],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    text=True,
                )
            )
        yield _Publishers(procs)
    finally:
        for proc in procs:
            assert proc.stdin is not None
            proc.stdin.close()  # ends the publisher's command loop: it closes its session and exits
        for proc in procs:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            assert proc.stdout is not None
            proc.stdout.close()


class _Arrivals:
    """Count and time of the latest arrival, updated by the one receiving thread of a subscription."""

    def __init__(self) -> None:
        self.count = 0
        self.last = 0.0

    def mark(self) -> None:
        self.count += 1
        self.last = time.perf_counter()

    def rate(self, start: float, per_arrival: int) -> float:
        return self.count * per_arrival / (self.last - start) if self.count else 0.0


def _per_batch(cpu_seconds: float, batches: int) -> float:
    return round(cpu_seconds / batches * 1e6, 1) if batches else 0.0


def _wait_until(predicate: Callable[[], bool], timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not predicate() and time.monotonic() < deadline:
        time.sleep(0.005)


def _secure_set(folder: str, actors: int) -> SecureSet:
    port = free_port()
    spec = SecureSet(
        folder=Path(folder),
        actor_ids=tuple(f"bench-{i}" for i in range(actors)),
        listen=(f"tls/127.0.0.1:{port}",),
        connect=(f"tls/localhost:{port}",),
    )
    write_secure_set(spec)
    return spec


def _receiver_config(shared_memory: bool, endpoint: str, secure: SecureSet | None) -> zenoh.Config:
    if secure is None:
        return bench_zenoh_config(shared_memory, listen=[endpoint])
    # The router's TLS and credentials on the receiving peer: the publishers' links are those of a secure run.
    # Access control stays off because the raw phase's key is outside the protocol; it is one key-expression
    # lookup per message at the router, beside TLS's encryption of every byte.
    conf = bench_zenoh_config(shared_memory, config_file=str(secure.config(ROUTER)), mode="peer")
    conf.insert_json5("access_control/enabled", "false")
    return conf


def bench_transport(
    actors: int = 2, batch_size: int = 16384, seconds: float = 3.0, shared_memory: bool = False, secure: bool = False
) -> dict[str, Any]:
    """Run both phases for ``seconds`` each; the keys are those of the module docstring plus counts.

    ``secure``: every link is mutual TLS with user/password authentication, as in a secure run
    (``ennc-ql secure init``'s files, in a temporary folder).
    """
    folder = tempfile.TemporaryDirectory(prefix="enncql-bench-") if secure else None
    spec = _secure_set(folder.name, actors) if folder is not None else None
    endpoint = spec.connect[0] if spec is not None else f"tcp/127.0.0.1:{free_port()}"
    ingest = ExperienceIntake(STORE_CAPACITY, FORMULATION)
    stored, raw = _Arrivals(), _Arrivals()

    def on_experience(msg: ExperienceBatch) -> None:
        ingest.on_experience(msg)
        stored.mark()

    with ExitStack() as stack:
        if folder is not None:
            stack.enter_context(folder)
        bar = stack.enter_context(ProgressBar("bench transport", total=3, unit="phases"))
        transport = stack.enter_context(ZenohTransport.open(_receiver_config(shared_memory, endpoint, spec)))
        transport.subscribe(DEFAULT_KEYS.experience(), ExperienceBatch, on_experience)
        raw_sub = transport.session.declare_subscriber(f"{RAW_KEY}/*", lambda _sample: raw.mark())
        stack.callback(raw_sub.undeclare)
        bar.show(status=f"starting {actors} publisher processes")
        publishers = stack.enter_context(_publishers(endpoint, actors, batch_size, shared_memory, spec))
        publishers.wait_ready()
        bar.mark(f"{actors} publishers matched", n=1)
        protocol = _phase(publishers, "protocol", seconds, stored, batch_size, bar)
        bar.mark(
            f"protocol path: {protocol.tuples_per_s / 1e6:.2f} M tuples/s, "
            f"{protocol.sent - ingest.figures().accepted} batches lost",
            n=2,
        )
        plain = _phase(publishers, "raw", seconds, raw, batch_size, bar)
        bar.mark(f"raw zenoh: {plain.tuples_per_s / 1e6:.2f} M tuples/s", n=3)
    return _figures(actors, batch_size, seconds, shared_memory, secure, ingest, protocol, plain, raw.count)


@dataclass(frozen=True, slots=True)
class _Phase:
    """What one phase measured: batches sent, tuples/s arrived, and the CPU seconds of each side."""

    sent: int
    tuples_per_s: float
    publisher_cpu: float
    receiver_cpu: float


def _phase(
    publishers: _Publishers, phase: str, seconds: float, arrivals: _Arrivals, batch_size: int, bar: ProgressBar
) -> _Phase:
    """``phase`` in every publisher at once, until everything they sent arrived (or the drain timed out)."""
    bar.show(status=f"{'protocol path' if phase == 'protocol' else 'raw zenoh'}, {seconds:g} s")
    start, cpu = time.perf_counter(), time.process_time()
    sent, publisher_cpu = publishers.run_phase(phase, seconds)
    _wait_until(lambda: arrivals.count >= sent, _DRAIN_TIMEOUT_S)
    return _Phase(sent, arrivals.rate(start, batch_size), publisher_cpu, time.process_time() - cpu)


def _figures(
    actors: int,
    batch_size: int,
    seconds: float,
    shared_memory: bool,
    secure: bool,
    ingest: ExperienceIntake,
    protocol: _Phase,
    plain: _Phase,
    raw_received: int,
) -> dict[str, Any]:
    figures = ingest.figures()
    stamp = FORMULATION.names
    return {
        "actors": actors,
        "batch_size": batch_size,
        "payload_bytes": len(encode(template_batch("bench-0", 0, batch_size, stamp, DIM))),
        "seconds": seconds,
        "shared_memory": shared_memory,
        "secure": secure,
        "tuples_per_s": round(protocol.tuples_per_s),
        "raw_zenoh_tuples_per_s": round(plain.tuples_per_s),
        "ratio": round(protocol.tuples_per_s / plain.tuples_per_s, 3) if plain.tuples_per_s else 0.0,
        "lost": protocol.sent - figures.accepted,
        "batches_sent": protocol.sent,
        "tuples_stored": figures.tuples_received,
        "gaps": figures.gaps,
        "duplicates": figures.duplicates,
        "raw_batches_sent": plain.sent,
        "raw_batches_received": raw_received,
        # CPU time per batch of each side (all threads, zenoh's included): what the rates cost, whatever else
        # the machine was doing meanwhile.
        "cpu_us_per_batch": {
            "receiver": _per_batch(protocol.receiver_cpu, protocol.sent),
            "publishers": _per_batch(protocol.publisher_cpu, protocol.sent),
            "raw_receiver": _per_batch(plain.receiver_cpu, plain.sent),
            "raw_publishers": _per_batch(plain.publisher_cpu, plain.sent),
        },
        "target": TARGET,
    }


def transport_table(out: dict[str, Any]) -> str:
    """The human-readable summary ``ennc-ql bench transport`` prints without ``--json``."""
    met = out["tuples_per_s"] >= TARGET["tuples_per_s"] and out["ratio"] >= TARGET["ratio"] and out["lost"] == 0
    return (
        f"{out['actors']} actors -> learner store, batches of {out['batch_size']} tuples "
        f"({out['payload_bytes'] / 1024:.0f} KiB), shared memory {'on' if out['shared_memory'] else 'off'}, "
        f"{'mutual TLS + passwords' if out['secure'] else 'plain TCP'}\n"
        f"  protocol path: {out['tuples_per_s'] / 1e6:6.2f} M tuples/s, lost {out['lost']}\n"
        f"  raw zenoh:     {out['raw_zenoh_tuples_per_s'] / 1e6:6.2f} M tuples/s\n"
        f"  ratio {out['ratio']:.2f} (target >= {TARGET['ratio']} with >= {TARGET['tuples_per_s'] / 1e6:.0f} M "
        f"tuples/s and nothing lost: {'met' if met else 'NOT met'})"
    )
