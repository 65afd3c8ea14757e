"""The learner's silences, as a client outside it sees them: the gaps between its policy broadcasts and between its
status messages, measured on the wire (written from docs/reference/protocol.md: the keys, and nothing of the project's
code).

Started beside a running ``ennc-ql up`` (it finds that run's learner among the processes and joins its loopback
endpoint as a peer), it listens until the learner has been silent for ``--quiet`` seconds after its first message,
then prints the longest gaps of each stream and every gap over ``--limit`` seconds::

    ennc-ql up --run-id p1 &
    python scripts/pauses.py runs/p1             # waits for the run's learner, then listens to its end
    python scripts/pauses.py runs/p1 --json      # one JSON object

The promise measured: policies every ``broadcast_interval`` (3 s) and status every ``status_interval`` (2 s),
throughout; a pause over 2 s past that is a defect.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import threading
import time
from pathlib import Path
from typing import Any

import psutil
import zenoh


def learner_flags(run_dir: Path, timeout: float) -> tuple[str, str]:
    """The endpoint and namespace of the learner process of ``run_dir`` (its command line), once it runs."""
    deadline = time.monotonic() + timeout
    wanted = str(run_dir)
    while time.monotonic() < deadline:
        for proc in psutil.process_iter(["cmdline"]):
            argv = proc.info["cmdline"] or []
            if "learner" in argv and "--run-dir" in argv and argv[argv.index("--run-dir") + 1].endswith(wanted):
                listen = argv[argv.index("--listen") + 1] if "--listen" in argv else None
                connect = argv[argv.index("--connect") + 1] if "--connect" in argv else None
                namespace = argv[argv.index("--namespace") + 1] if "--namespace" in argv else ""
                endpoint = listen or connect
                if endpoint:
                    return endpoint, namespace
        time.sleep(0.2)
    raise SystemExit(f"pauses: no learner of {run_dir} started within {timeout:g} s")


def listen(endpoint: str, namespace: str, quiet: float) -> dict[str, list[float]]:
    """Arrival times (monotonic seconds) of every policy and learner status message, until ``quiet`` seconds of
    silence after the first."""
    root = f"{namespace}/enncql/v2" if namespace else "enncql/v2"
    arrivals: dict[str, list[float]] = {"policy": [], "status": []}
    lock = threading.Lock()

    def heard(kind: str) -> Any:
        def on_sample(sample: zenoh.Sample) -> None:
            with lock:
                arrivals[kind].append(time.monotonic())

        return on_sample

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        subscribers = [
            session.declare_subscriber(f"{root}/policy", heard("policy")),
            session.declare_subscriber(f"{root}/status/learner", heard("status")),
        ]
        while True:
            time.sleep(0.5)
            with lock:
                last = max((t[-1] for t in arrivals.values() if t), default=None)
            if last is not None and time.monotonic() - last > quiet:
                break
        for subscriber in subscribers:
            subscriber.undeclare()
    return arrivals


def gaps(times: list[float]) -> list[tuple[float, float]]:
    """(seconds since the stream's first message, gap before it) for every message after the first."""
    return [(b - times[0], b - a) for a, b in itertools.pairwise(times)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="the run folder of the running ennc-ql up (runs/<id>)")
    parser.add_argument("--quiet", type=float, default=20.0, help="seconds of silence that end the listening")
    parser.add_argument("--limit", type=float, default=5.0, help="list every gap longer than this (seconds)")
    parser.add_argument("--wait", type=float, default=120.0, help="seconds to wait for the learner to start")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    endpoint, namespace = learner_flags(args.run_dir, args.wait)
    arrivals = listen(endpoint, namespace, args.quiet)
    out: dict[str, Any] = {"endpoint": endpoint, "namespace": namespace}
    for kind, times in arrivals.items():
        found = gaps(times)
        longest = sorted(found, key=lambda g: -g[1])[:5]
        out[kind] = {
            "messages": len(times),
            "span_s": round(times[-1] - times[0], 1) if times else 0.0,
            "max_gap_s": round(max((g for _, g in found), default=0.0), 2),
            "longest": [[round(at, 1), round(gap, 2)] for at, gap in longest],
            "over_limit": [[round(at, 1), round(gap, 2)] for at, gap in found if gap > args.limit],
        }
    if args.json:
        print(json.dumps(out))
    else:
        for kind in arrivals:
            o = out[kind]
            print(
                f"{kind}: {o['messages']} messages over {o['span_s']} s, longest gap {o['max_gap_s']} s; over "
                f"{args.limit:g} s: {o['over_limit'] or 'none'}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
