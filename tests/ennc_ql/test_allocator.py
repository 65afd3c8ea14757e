"""The malloc settings every ennc-ql process applies: fresh ~1 MB payloads handed to Zenoh stop page-faulting."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

# Page faults per put of a fresh 1 MiB payload (Zenoh frees it later, from its own thread), as an actor sends.
PUTS_SCRIPT = """
import os, resource, sys
import zenoh
from tools.allocator import keep_freed_memory
if sys.argv[1] == "tuned":
    assert keep_freed_memory()
from protocol import zenoh_config
base = os.urandom(1 << 20)
parts = [memoryview(base)[:1000], memoryview(base)[1000:]]
with zenoh.open(zenoh_config()) as session:
    publisher = session.declare_publisher("enncql-test/alloc")
    for _ in range(20):
        publisher.put(b"".join(parts))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(100):
        publisher.put(b"".join(parts))
    print((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 100)
    publisher.undeclare()
"""


def faults_per_put(mode: str) -> float:
    done = subprocess.run(
        [sys.executable, "-c", PUTS_SCRIPT, mode], cwd=REPO, capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    return float(done.stdout.strip())


def test_fresh_payloads_reuse_freed_memory_instead_of_faulting_it_in() -> None:
    default, tuned = faults_per_put("default"), faults_per_put("tuned")
    # 1 MiB is 256 pages: by default (nearly) every page of every payload is faulted in anew.
    assert default > 100
    assert tuned < 10
