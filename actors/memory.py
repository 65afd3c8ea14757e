"""Giving back what an actor process maps but no longer needs: the JIT compiler's machine code, once the loop's
kernels are compiled.

Usage::

    released = release_compiler_code()   # bytes of the mappings released (0 off Linux or without numba's LLVM)
"""

from __future__ import annotations

import ctypes
import functools
import logging
import os
import sys

log = logging.getLogger(__name__)

COMPILER_LIBRARY = "libllvmlite.so"
"""numba's LLVM: the compiler that turns the simulator's kernels into machine code, or links them from numba's cache."""
_MADV_DONTNEED = 4


def release_compiler_code() -> int:
    """Drop this process's resident pages of the JIT compiler's machine code; the bytes of the mappings released.

    Once a process has compiled (or loaded from numba's cache) the kernels it runs, LLVM's code is not executed
    again, yet its pages stay mapped: 69-108 MiB of an actor's RSS, depending on how the kernel maps file pages
    (docs/performance.md, "Memory of the processes"). ``MADV_DONTNEED`` on the library's executable mappings only
    removes them from this process's page tables: they are private, read-only and never written, so a later
    compilation faults them back in from the file, unchanged. Writable or relocated mappings are left alone (dropping
    those would lose their contents). Reading the mappings costs ~1 ms, so they are found once; a call after that is
    one ``madvise`` per mapping (~4 µs)."""
    spans = _compiler_spans()
    if not spans:
        return 0
    madvise = _libc().madvise
    released = 0
    for start, size in spans:
        if madvise(start, size, _MADV_DONTNEED) == 0:
            released += size
        else:
            log.warning("could not release the compiler's code pages: %s", os.strerror(ctypes.get_errno()))
    return released


_spans: list[tuple[int, int]] = []
_unreadable: list[OSError] = []
"""Why the mappings could not be read, once (then nothing is released and nothing is said again)."""


def _compiler_spans() -> list[tuple[int, int]]:
    """(start, size) of the library's executable mappings; empty off Linux, where the mappings cannot be read, or
    before the library is loaded (looked for again next time: a shared library, once loaded, stays where it is)."""
    if _spans or _unreadable or not sys.platform.startswith("linux"):
        return _spans
    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as maps:
            lines = maps.readlines()
    except OSError as e:
        _unreadable.append(e)
        log.warning("the compiler's code pages stay resident: cannot read /proc/self/maps (%s)", e)
        return _spans
    for line in lines:
        fields = line.split(maxsplit=5)
        if len(fields) == 6 and fields[1] == "r-xp" and fields[5].rstrip("\n").endswith(COMPILER_LIBRARY):
            lo, hi = (int(x, 16) for x in fields[0].split("-"))
            _spans.append((lo, hi - lo))
    return _spans


@functools.cache
def _libc() -> ctypes.CDLL:
    libc = ctypes.CDLL(None, use_errno=True)
    libc.madvise.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
    return libc
