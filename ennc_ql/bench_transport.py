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

The publishers are ``python -m ennc_ql.bench_transport --publisher ...`` subprocesses driven by one line per
command on stdin (``protocol SECONDS`` or ``raw SECONDS``); they answer ``ready`` once the receiver matches and
``sent BATCHES`` after each phase, and exit when stdin closes. The parent starts each phase in all of them at once.
"""

from __future__ import annotations

import argparse
import logging
import secrets
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from ennc_ql.allocator import keep_freed_memory
from ennc_ql.config import positive
from ennc_ql.progress import ProgressBar
from ennc_ql.secure import SecureSet, write_secure_set
from ennc_ql.system import free_port
from protocol import DEFAULT_KEYS, N_ACTIONS, ExperienceBatch, ZenohTransport, encode, zenoh_config
from protocol.security import ROUTER
from sim.features import FEATURIZERS, FORMULATIONS

log = logging.getLogger(__name__)

FORMULATION = FORMULATIONS["paper"]
"""What the batches are stamped with and the receiver stores: collab6d (d = 6), as in every figure measured so far."""
DIM = FEATURIZERS[FORMULATION.featurizer]
RAW_KEY = "enncql-bench/raw"
"""Outside the protocol's key space: the raw payloads are not messages."""
STORE_CAPACITY = 1 << 20
"""Tuples the receiver's store keeps (the learner's default is of the same order)."""
TARGET = {"tuples_per_s": 5e6, "ratio": 0.5, "lost": 0}
_STARTUP_TIMEOUT_S = 60.0
_DRAIN_TIMEOUT_S = 30.0


def template_batch(actor_id: str, incarnation: int, batch_size: int, seed: int = 0) -> ExperienceBatch:
    """A batch of ``batch_size`` random valid tuples with seq 0; publishers send it again under each seq."""
    rng = np.random.default_rng(seed)
    return ExperienceBatch(
        actor_id=actor_id,
        incarnation=incarnation,
        seq=0,
        policy_version=0,
        featurizer=FORMULATION.featurizer,
        reward_function=FORMULATION.reward,
        action_set=FORMULATION.actions,
        robot=rng.integers(0, 10, batch_size, dtype=np.int16),
        state=rng.random((batch_size, DIM), dtype=np.float32),
        action=rng.integers(0, N_ACTIONS, batch_size, dtype=np.uint8),
        reward=rng.random(batch_size, dtype=np.float32),
        next_state=rng.random((batch_size, DIM), dtype=np.float32),
        done=rng.random(batch_size) < 0.01,
    )


def _config(shared_memory: bool, **kwargs: Any) -> zenoh.Config:
    conf = zenoh_config(**kwargs)
    conf.insert_json5("transport/shared_memory/enabled", "true" if shared_memory else "false")
    return conf


# --- publisher subprocess ------------------------------------------------------------------------------------


def _publish_protocol(transport: ZenohTransport, template: ExperienceBatch, first_seq: int, seconds: float) -> int:
    """Publish batches first_seq, first_seq + 1, ... for ``seconds``; how many were sent."""
    key = transport.keys.experience(template.actor_id)
    sent = 0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        # A new message per batch, as an actor sends them: construction and encoding both validate it.
        batch = ExperienceBatch(
            actor_id=template.actor_id,
            incarnation=template.incarnation,
            seq=first_seq + sent,
            policy_version=template.policy_version,
            featurizer=template.featurizer,
            reward_function=template.reward_function,
            action_set=template.action_set,
            robot=template.robot,
            state=template.state,
            action=template.action,
            reward=template.reward,
            next_state=template.next_state,
            done=template.done,
        )
        transport.publish(key, batch)
        sent += 1
    return sent


def _publish_raw(publisher: zenoh.Publisher, payload: bytes, seconds: float) -> int:
    sent = 0
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        publisher.put(payload)
        sent += 1
    return sent


def _answer(line: str) -> None:
    # stdout is this subprocess's channel to the parent, not a terminal.
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def publisher_main(
    endpoint: str, actor_id: str, batch_size: int, shared_memory: bool, config_file: str | None = None
) -> int:
    """Body of a publisher subprocess: serve the parent's commands on stdin until it closes."""
    template = template_batch(actor_id, secrets.randbits(64), batch_size, seed=secrets.randbits(32))
    payload = encode(template)
    conf = _config(shared_memory, connect=[endpoint], config_file=config_file, mode="peer")
    with ZenohTransport.open(conf) as transport:
        key = transport.keys.experience(actor_id)
        raw = transport.session.declare_publisher(
            f"{RAW_KEY}/{actor_id}",
            congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE,
        )
        try:
            # zenoh 1.10's stub says bool; the value is a MatchingStatus, always truthy.
            raw_status: Any = raw.matching_status
            deadline = time.monotonic() + _STARTUP_TIMEOUT_S
            while not (transport.has_subscribers(key) and raw_status.matching):
                if time.monotonic() > deadline:
                    log.error("publisher %s: no receiver matched in %.0f s", actor_id, _STARTUP_TIMEOUT_S)
                    return 1
                time.sleep(0.01)
                raw_status = raw.matching_status
            _answer("ready")
            seq = 0
            for line in sys.stdin:
                phase, seconds = line.split()
                cpu = time.process_time()
                if phase == "protocol":
                    sent = _publish_protocol(transport, template, seq, float(seconds))
                    seq += sent
                else:
                    sent = _publish_raw(raw, payload, float(seconds))
                _answer(f"sent {sent} {time.process_time() - cpu}")
        finally:
            raw.undeclare()
    return 0


# --- driver and receiver -------------------------------------------------------------------------------------


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
            self._answer(proc, _STARTUP_TIMEOUT_S, "ready")

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
    try:
        for i in range(actors):
            argv = ["--publisher", endpoint, f"bench-{i}", str(batch_size), shm_flag]
            if secure is not None:
                argv += ["--zenoh-config", str(secure.config(f"bench-{i}"))]
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "ennc_ql.bench_transport", *argv],
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
        return _config(shared_memory, listen=[endpoint])
    # The router's TLS and credentials on the receiving peer: the publishers' links are those of a secure run.
    # Access control stays off because the raw phase's key is outside the protocol; it is one key-expression
    # lookup per message at the router, beside TLS's encryption of every byte.
    conf = _config(shared_memory, config_file=str(secure.config(ROUTER)), mode="peer")
    conf.insert_json5("access_control/enabled", "false")
    return conf


def bench_transport(
    actors: int = 2, batch_size: int = 16384, seconds: float = 3.0, shared_memory: bool = False, secure: bool = False
) -> dict[str, Any]:
    """Run both phases for ``seconds`` each; the keys are those of the module docstring plus counts.

    ``secure``: every link is mutual TLS with user/password authentication, as in a secure run
    (``ennc-ql secure init``'s files, in a temporary folder).
    """
    # Imported here, not at the top: the publisher subprocesses run this module and need no learner.
    from learner.intake import ExperienceIntake

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

        bar.show(status=f"protocol path, {seconds:g} s")
        start, cpu = time.perf_counter(), time.process_time()
        sent, publisher_cpu = publishers.run_phase("protocol", seconds)
        _wait_until(lambda: stored.count >= sent, _DRAIN_TIMEOUT_S)
        tuples_per_s = stored.rate(start, batch_size)
        receiver_cpu = time.process_time() - cpu
        bar.mark(
            f"protocol path: {tuples_per_s / 1e6:.2f} M tuples/s, {sent - ingest.figures().accepted} batches lost", n=2
        )

        bar.show(status=f"raw zenoh, {seconds:g} s")
        start, cpu = time.perf_counter(), time.process_time()
        raw_sent, raw_publisher_cpu = publishers.run_phase("raw", seconds)
        _wait_until(lambda: raw.count >= raw_sent, _DRAIN_TIMEOUT_S)
        raw_tuples_per_s = raw.rate(start, batch_size)
        raw_receiver_cpu = time.process_time() - cpu
        bar.mark(f"raw zenoh: {raw_tuples_per_s / 1e6:.2f} M tuples/s", n=3)

    figures = ingest.figures()
    return {
        "actors": actors,
        "batch_size": batch_size,
        "payload_bytes": len(encode(template_batch("bench-0", 0, batch_size))),
        "seconds": seconds,
        "shared_memory": shared_memory,
        "secure": secure,
        "tuples_per_s": round(tuples_per_s),
        "raw_zenoh_tuples_per_s": round(raw_tuples_per_s),
        "ratio": round(tuples_per_s / raw_tuples_per_s, 3) if raw_tuples_per_s else 0.0,
        "lost": sent - figures.accepted,
        "batches_sent": sent,
        "tuples_stored": figures.tuples_received,
        "gaps": figures.gaps,
        "duplicates": figures.duplicates,
        "raw_batches_sent": raw_sent,
        "raw_batches_received": raw.count,
        # CPU time per batch of each side (all threads, zenoh's included): what the rates cost, whatever else
        # the machine was doing meanwhile.
        "cpu_us_per_batch": {
            "receiver": _per_batch(receiver_cpu, sent),
            "publishers": _per_batch(publisher_cpu, sent),
            "raw_receiver": _per_batch(raw_receiver_cpu, raw_sent),
            "raw_publishers": _per_batch(raw_publisher_cpu, raw_sent),
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


def add_bench_transport_args(parser: argparse.ArgumentParser) -> None:
    """The ``bench transport`` flags (its measuring time per phase is the bench command's ``--seconds``)."""
    parser.add_argument("--actors", type=positive(int), default=2, help="transport: publisher processes (default 2)")
    parser.add_argument(
        "--batch-size", type=positive(int), default=16384, help="transport: tuples per batch (default 16384)"
    )
    parser.add_argument(
        "--shared-memory",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="transport: let zenoh use shared memory, as between processes of one host (default: off, as across hosts)",
    )
    parser.add_argument(
        "--secure",
        action="store_true",
        help="transport: mutual TLS and password authentication on every link, as in a secure run",
    )


def _publisher_entry(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m ennc_ql.bench_transport", description="bench publisher")
    parser.add_argument("--publisher", nargs=3, metavar=("ENDPOINT", "ACTOR_ID", "BATCH_SIZE"), required=True)
    parser.add_argument("--shared-memory", action=argparse.BooleanOptionalAction, default=False)
    parser.add_argument("--zenoh-config", help="the publisher's zenoh configuration (a secure run's)")
    args = parser.parse_args(argv)
    endpoint, actor_id, batch_size = args.publisher
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(asctime)s %(name)s: %(message)s")
    keep_freed_memory()  # as every ennc-ql process does: the publishers stand for actors
    return publisher_main(endpoint, actor_id, int(batch_size), args.shared_memory, args.zenoh_config)


if __name__ == "__main__":
    sys.exit(_publisher_entry(sys.argv[1:]))
