"""``ennc-ql bench broadcast``: what a policy broadcast weighs and costs against its prototype count.

For each count P of prototypes per action, a policy of the scenario's shape (L = 8 actions, d = 6, one Q-table row
per robot) with random prototypes is turned into the learner's broadcast, and each step an update goes through is
timed, median over ``rounds``:

* ``build_ms``: ``policy_update`` (the learner's Policy -> PolicyUpdate);
* ``encode_ms`` / ``decode_ms``: the codec, both ways, validation included;
* ``apply_ms``: what an actor does with a decoded update before its next decision (``policy_from_update``, a
  ``TabularAgent`` over it, and the first search, which builds the nearest-prototype index);
* ``delivery_ms``: from the learner's publish to the update decoded in a subscriber's handler, over Zenoh on
  loopback (TCP, shared memory off, as across machines).

``bytes`` is the encoded message. Usage::

    out = bench_broadcast(prototypes_per_action=(100, 1000), rounds=5)
    out["rows"][0]["bytes"], out["rows"][0]["delivery_ms"]
"""

from __future__ import annotations

import dataclasses
import statistics
import threading
import time
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np

from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.wire import policy_from_update, policy_update
from protocol import DEFAULT_KEYS, N_ACTIONS, PolicyUpdate, ZenohTransport, decode_as, encode, zenoh_config
from sim import FORMULATIONS, scenario
from tools.progress import ProgressBar
from tools.system import free_port

DIM = 6
_DELIVERY_TIMEOUT_S = 30.0


def random_policy(prototypes_per_action: int, n_robots: int, seed: int = 0) -> Policy:
    """A collab6d policy with ``prototypes_per_action`` random prototypes per action and random Q tables."""
    rng = np.random.default_rng(seed)
    size = prototypes_per_action * N_ACTIONS
    disc = Discretization(
        prototypes=rng.random((size, DIM)).astype(np.float32),
        labels=rng.random(size).astype(np.float32),
        offsets=np.arange(N_ACTIONS + 1, dtype=np.int64) * prototypes_per_action,
        scale=np.ones(DIM, np.float32),
    )
    return Policy(
        formulation=FORMULATIONS["paper"],
        discretization=disc,
        tables=rng.random((n_robots, size)).astype(np.float32),
        robot_table=np.arange(n_robots),
        visits=rng.integers(0, 1000, (n_robots, size)).astype(np.uint64),
        version=1,
    )


def _median_ms(fn: Callable[[], object], rounds: int) -> float:
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return round(statistics.median(times) * 1e3, 3)


def _apply(update: PolicyUpdate, n_robots: int, probe: np.ndarray) -> None:
    agent = TabularAgent(policy_from_update(update, n_robots, FORMULATIONS["paper"]), Phase2Config())
    agent.cells(probe)


class _Arrivals:
    def __init__(self) -> None:
        self.at: dict[int, float] = {}
        self.changed = threading.Condition()

    def on_update(self, msg: PolicyUpdate) -> None:
        with self.changed:
            self.at[msg.version] = time.perf_counter()
            self.changed.notify_all()

    def wait(self, version: int) -> float:
        with self.changed:
            if not self.changed.wait_for(lambda: version in self.at, _DELIVERY_TIMEOUT_S):
                raise RuntimeError(f"bench broadcast: version {version} not delivered in {_DELIVERY_TIMEOUT_S:.0f} s")
            return self.at[version]


def bench_broadcast(
    prototypes_per_action: Sequence[int] = (100, 300, 1000, 3000, 10000), rounds: int = 5, scenario_name: str = ""
) -> dict[str, Any]:
    """The figures of the module docstring, one row per prototype count."""
    cfg = scenario(scenario_name or "cmommt-v1")
    probe = np.random.default_rng(1).random((1, DIM)).astype(np.float32)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rows: list[dict[str, Any]] = []
    listen = zenoh_config(listen=[endpoint])
    connect = zenoh_config(connect=[endpoint])
    for conf in (listen, connect):
        conf.insert_json5("transport/shared_memory/enabled", "false")
    arrivals = _Arrivals()
    with (
        ProgressBar("bench broadcast", total=len(prototypes_per_action), unit="sizes") as bar,
        ZenohTransport.open(listen) as learner,
        ZenohTransport.open(connect) as actor,
    ):
        actor.subscribe(DEFAULT_KEYS.policy(), PolicyUpdate, arrivals.on_update)
        deadline = time.monotonic() + _DELIVERY_TIMEOUT_S
        while not learner.has_subscribers(DEFAULT_KEYS.policy()):
            if time.monotonic() > deadline:
                raise RuntimeError("bench broadcast: the subscriber never matched")
            time.sleep(0.01)
        version = 0
        for k in prototypes_per_action:
            bar.show(status=f"{k} prototypes per action")
            policy = random_policy(k, cfg.n_robots)
            update = policy_update(policy, cfg.name)
            data = encode(update)
            delivery = []
            for _ in range(rounds):
                version += 1
                msg = policy_update(dataclasses.replace(policy, version=version), cfg.name)
                start = time.perf_counter()
                learner.publish(DEFAULT_KEYS.policy(), msg)
                delivery.append(arrivals.wait(msg.version) - start)
            rows.append(
                {
                    "prototypes_per_action": k,
                    "bytes": len(data),
                    "build_ms": _median_ms(partial(policy_update, policy, cfg.name), rounds),
                    "encode_ms": _median_ms(partial(encode, update), rounds),
                    "decode_ms": _median_ms(partial(decode_as, data, PolicyUpdate), rounds),
                    "apply_ms": _median_ms(partial(_apply, update, cfg.n_robots, probe), rounds),
                    "delivery_ms": round(statistics.median(delivery) * 1e3, 3),
                }
            )
            bar.mark(f"{k} prototypes per action: {len(data) / 1e6:.2f} MB", n=len(rows))
    return {"robots": cfg.n_robots, "actions": N_ACTIONS, "dim": DIM, "rounds": rounds, "rows": rows}


def broadcast_table(out: dict[str, Any]) -> str:
    """The human-readable table ``ennc-ql bench broadcast`` prints without ``--json``."""
    head = (
        f"policy broadcast, {out['robots']} robots x {out['actions']} actions, d = {out['dim']}, "
        f"median of {out['rounds']} rounds\n"
        f"{'P/action':>9} {'MB':>7} {'build ms':>9} {'encode ms':>10} {'decode ms':>10} {'apply ms':>9} "
        f"{'delivery ms':>12}"
    )
    lines = [
        f"{r['prototypes_per_action']:>9} {r['bytes'] / 1e6:>7.2f} {r['build_ms']:>9.2f} {r['encode_ms']:>10.2f} "
        f"{r['decode_ms']:>10.2f} {r['apply_ms']:>9.2f} {r['delivery_ms']:>12.2f}"
        for r in out["rows"]
    ]
    return "\n".join([head, *lines])
