"""Durable file writes: the one atomic-write helper behind the policy file and the learner's checkpoint.

Usage::

    save_npz_atomic(Path("runs/x/checkpoint.npz"), {"tables": tables, "visits": visits})
    write_atomic(Path("runs/x/policy-version.json"), b'{"published": 7}')
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import BinaryIO

import numpy as np


def save_npz_atomic(path: Path, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write ``arrays`` as an uncompressed ``.npz`` at ``path``, atomically (see :func:`write_atomic`)."""
    return _write(path, lambda f: np.savez(f, **arrays))  # type: ignore[arg-type]


def write_atomic(path: Path, data: bytes) -> Path:
    """Write ``data`` at ``path``: a temporary file in the same folder, fsynced, then renamed over the target, so a
    reader (or a process killed mid-write) only ever sees the old or the new file."""
    return _write(path, lambda f: f.write(data))


def _write(path: Path, fill: Callable[[BinaryIO], object]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            fill(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    # The rename itself is durable only once the folder's entry is on disk.
    folder = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(folder)
    finally:
        os.close(folder)
    return path
