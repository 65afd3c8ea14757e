"""A publisher process of ``ennc-ql bench transport``: it stands for an actor, publishing experience as fast as the
receiver takes it. Started as ``python -m tools.bench.publisher ENDPOINT ACTOR_ID BATCH_SIZE --stamp FEATURIZER
REWARD_FUNCTION ACTION_SET --dim D`` and driven by one line per command on stdin (``protocol SECONDS`` or ``raw
SECONDS``): it answers ``ready`` once the receiver matches and ``sent BATCHES CPU_SECONDS`` after each phase, and
exits when stdin closes.

It imports neither the simulator nor the learner: the formulation stamped on its batches comes on its command line,
so that sixteen of them start in seconds on two cores.
"""

from __future__ import annotations

import argparse
import logging
import secrets
import sys
import time
from typing import Any

import numpy as np
import zenoh

from protocol import N_ACTIONS, ExperienceBatch, ZenohTransport, encode, zenoh_config
from tools.allocator import keep_freed_memory

log = logging.getLogger(__name__)

RAW_KEY = "enncql-bench/raw"
"""Outside the protocol's key space: the raw payloads are not messages."""
STARTUP_TIMEOUT_S = 60.0


def bench_zenoh_config(shared_memory: bool, **kwargs: Any) -> zenoh.Config:
    """``protocol.zenoh_config(**kwargs)`` with Zenoh's shared memory on or off."""
    conf = zenoh_config(**kwargs)
    conf.insert_json5("transport/shared_memory/enabled", "true" if shared_memory else "false")
    return conf


def template_batch(
    actor_id: str, incarnation: int, batch_size: int, stamp: tuple[str, str, str], dim: int, seed: int = 0
) -> ExperienceBatch:
    """A batch of ``batch_size`` random valid tuples of dimension ``dim`` with seq 0, stamped with ``stamp``
    (featurizer, reward function, action set); publishers send it again under each seq."""
    rng = np.random.default_rng(seed)
    featurizer, reward_function, action_set = stamp
    return ExperienceBatch(
        actor_id=actor_id,
        incarnation=incarnation,
        seq=0,
        policy_version=0,
        featurizer=featurizer,
        reward_function=reward_function,
        action_set=action_set,
        robot=rng.integers(0, 10, batch_size, dtype=np.int16),
        state=rng.random((batch_size, dim), dtype=np.float32),
        action=rng.integers(0, N_ACTIONS, batch_size, dtype=np.uint8),
        reward=rng.random(batch_size, dtype=np.float32),
        next_state=rng.random((batch_size, dim), dtype=np.float32),
        done=rng.random(batch_size) < 0.01,
    )


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


def _await_receiver(transport: ZenohTransport, key: str, raw: zenoh.Publisher, actor_id: str) -> bool:
    """Until the receiver's subscriptions match both keys (False after STARTUP_TIMEOUT_S)."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    # zenoh 1.10's stub says bool; the value is a MatchingStatus, always truthy.
    raw_status: Any = raw.matching_status
    while not (transport.has_subscribers(key) and raw_status.matching):
        if time.monotonic() > deadline:
            log.error("publisher %s: no receiver matched in %.0f s", actor_id, STARTUP_TIMEOUT_S)
            return False
        time.sleep(0.01)
        raw_status = raw.matching_status
    return True


def publisher_main(
    endpoint: str,
    actor_id: str,
    batch_size: int,
    stamp: tuple[str, str, str],
    dim: int,
    shared_memory: bool,
    config_file: str | None = None,
) -> int:
    """Serve the parent's commands on stdin until it closes."""
    template = template_batch(actor_id, secrets.randbits(64), batch_size, stamp, dim, seed=secrets.randbits(32))
    payload = encode(template)
    conf = bench_zenoh_config(shared_memory, connect=[endpoint], config_file=config_file, mode="peer")
    with ZenohTransport.open(conf) as transport:
        key = transport.keys.experience(actor_id)
        raw = transport.session.declare_publisher(
            f"{RAW_KEY}/{actor_id}",
            congestion_control=zenoh.CongestionControl.BLOCK,
            reliability=zenoh.Reliability.RELIABLE,
        )
        try:
            if not _await_receiver(transport, key, raw, actor_id):
                return 1
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


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="python -m tools.bench.publisher", description="bench transport publisher")
    parser.add_argument("endpoint")
    parser.add_argument("actor_id")
    parser.add_argument("batch_size", type=int)
    parser.add_argument("--stamp", nargs=3, metavar=("FEATURIZER", "REWARD_FUNCTION", "ACTION_SET"), required=True)
    parser.add_argument("--dim", type=int, required=True, help="the featurizer's state dimension")
    parser.add_argument("--shared-memory", action=argparse.BooleanOptionalAction, default=False)
    parser.add_argument("--zenoh-config", help="the publisher's zenoh configuration (a secure run's)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(asctime)s %(name)s: %(message)s")
    keep_freed_memory()  # as every ennc-ql process does: the publishers stand for actors
    stamp = (args.stamp[0], args.stamp[1], args.stamp[2])
    return publisher_main(
        args.endpoint, args.actor_id, args.batch_size, stamp, args.dim, args.shared_memory, args.zenoh_config
    )


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
