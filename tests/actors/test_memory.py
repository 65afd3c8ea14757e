"""Releasing the JIT compiler's code pages: the actor's RSS loses them, and numba still compiles and runs after."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

# Run in a fresh interpreter: the pytest worker's own mappings (and what other tests compiled) must not blur the
# measurement, and a broken release must crash a child, not the suite.
CHILD = r"""
import json
import numba
from actors.memory import COMPILER_LIBRARY, release_compiler_code

def resident_kib():
    total, inside = 0, False
    with open("/proc/self/smaps") as smaps:
        for line in smaps:
            fields = line.split()
            if "-" in fields[0] and not fields[0].endswith(":"):
                inside = len(fields) >= 6 and fields[1] == "r-xp" and fields[5].endswith(COMPILER_LIBRARY)
            elif inside and fields[0] == "Rss:":
                total += int(fields[1])
    return total

@numba.njit(cache=False)
def before(n):
    return sum(range(n))

first = before(10)
held = resident_kib()
released = release_compiler_code()
dropped = resident_kib()

@numba.njit(cache=False)
def after(x):
    return x * 3 + 1

print(json.dumps({"held": held, "released": released, "dropped": dropped, "first": first,
                  "again": before(100), "new": after(5), "refaulted": resident_kib()}))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the release reads /proc and calls Linux's madvise")
def test_release_drops_the_compilers_pages_and_numba_still_compiles() -> None:
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=120, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["held"] > 8 * 1024, r  # LLVM's code is resident after a compilation: tens of MiB
    assert r["released"] >= r["held"] * 1024  # every executable mapping of the library was released, whole
    assert r["dropped"] < r["held"] / 4, r  # ... and its pages left the process
    # The compiled function still runs, and a new compilation faults the compiler back in and works.
    assert (r["first"], r["again"], r["new"]) == (45, 4950, 16)
    assert r["refaulted"] > r["dropped"], r


def test_unreadable_mappings_release_nothing_and_say_so_once(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    from actors import memory

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise PermissionError("no /proc here")

    monkeypatch.setattr(memory.sys, "platform", "linux")
    monkeypatch.setattr(memory, "_spans", [])
    monkeypatch.setattr(memory, "_unreadable", [])
    monkeypatch.setattr(memory, "open", refuse, raising=False)
    with caplog.at_level("WARNING", logger="actors.memory"):
        assert memory.release_compiler_code() == 0
        assert memory.release_compiler_code() == 0
    assert [r.getMessage() for r in caplog.records] == [
        "the compiler's code pages stay resident: cannot read /proc/self/maps (no /proc here)"
    ]
