"""Reproducer of a memory retention in eclipse-zenoh 1.10.2, seen in ``ennc-ql chaos``'s soak: a router keeps about
20 MB (plain TCP) after every client session that published a few messages of 10 kB or more has closed, even when
nobody subscribes to them. In a run the router and the actors grow by that much at every learner restart (the
learner's new session publishes policies), and by nothing else: not with time, traffic, router restarts or stopped
actors. Run it again on a new zenoh release before removing the note in docs/performance.md::

    .venv/bin/python scripts/zenoh_session_leak.py            # RSS after each of 8 short-lived publishing sessions
    .venv/bin/python scripts/zenoh_session_leak.py --size 1000  # small messages: flat

Measured on the development machine: 50, 71, 91, 111, 131, ... MB with ``--size 60000``; 30 MB flat with
``--size 1000``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import psutil
import zenoh

from tools.system import free_port

CLIENT = r"""
import json, sys, time, zenoh
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("scouting/multicast/enabled", "false")
conf.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
with zenoh.open(conf) as session:
    for _ in range(5):
        session.put("leak/unsubscribed", b"x" * int(sys.argv[2]))
        time.sleep(0.05)
    time.sleep(0.5)
"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=60_000, help="bytes per message (default 60000)")
    parser.add_argument("--sessions", type=int, default=8, help="short-lived client sessions (default 8)")
    args = parser.parse_args()
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    me = psutil.Process()
    with zenoh.open(conf):
        for i in range(args.sessions):
            subprocess.run([sys.executable, "-c", CLIENT, endpoint, str(args.size)], check=True)
            time.sleep(0.3)
            print(f"after session {i + 1}: router RSS {me.memory_info().rss / 1e6:.0f} MB", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
