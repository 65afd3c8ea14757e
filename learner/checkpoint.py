"""The learner's checkpoint: one ``.npz`` in the run folder, written atomically (temporary file, fsync, rename).

Beside it, the version mark: the highest policy version ever broadcast, written (fsynced) before each broadcast,
so a learner resumed from an older checkpoint never reuses a version the killed one sent.

Usage::

    checkpointer = Checkpointer(run_dir)
    checkpointer.save(arrays, meta)          # arrays of the intake and policy state, JSON-able meta
    arrays, meta = checkpointer.load()       # raises CheckpointError if there is none, it is unreadable or not finite
    policy_problem(run_dir / "checkpoint.npz")  # None, or what makes its policy unusable (a NaN in a Q table)
    mark = VersionMark(run_dir)
    mark.record(7)                           # before version 7 goes out
    mark.load()                              # 7 (0 when no version was ever broadcast)
    kept_visits(run_dir / "checkpoint.npz")  # visits applied and dropped (the exactly-once check of the increments)
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.files import save_npz_atomic, write_atomic
from algorithm.policy_file import FLOATS, non_finite

CHECKPOINT = "checkpoint.npz"
VERSION_MARK = "policy-version.json"


class CheckpointError(RuntimeError):
    """No readable checkpoint where one was asked for."""


class Checkpointer:
    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / CHECKPOINT

    def save(self, arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Path:
        blob = np.frombuffer(json.dumps(meta, default=str).encode(), np.uint8)
        return save_npz_atomic(self.path, {**arrays, "meta": blob})

    def load(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        if not self.path.exists():
            raise CheckpointError(f"--resume: no checkpoint at {self.path}")
        try:
            with np.load(self.path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
            meta: dict[str, Any] = json.loads(arrays.pop("meta").tobytes().decode())
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
            raise CheckpointError(f"--resume: unreadable checkpoint {self.path}: {exc}") from None
        problem = non_finite(arrays)
        if problem:
            raise CheckpointError(f"--resume: {self.path}: {problem}; a run cannot continue from it")
        return arrays, meta


def policy_problem(path: Path) -> str | None:
    """What makes the policy a checkpoint holds unusable (:func:`~algorithm.policy_file.non_finite`), or None; read
    without the rest of the checkpoint (its store of experience may take hundreds of MB). A checkpoint that cannot be
    read at all is :meth:`Checkpointer.load`'s to report."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return non_finite({name: data[name] for name in FLOATS if name in data.files})
    except (OSError, ValueError, zipfile.BadZipFile):
        return None


def kept_visits(path: Path) -> tuple[int, int]:
    """Visits a checkpoint accounts for: those applied (in its tables, carried over by a refit, or in the increments
    acknowledged but not merged yet, none after a run's final checkpoint), and those acknowledged and dropped (stale
    increments). Every acknowledged increment applied, none stale: ``(acknowledged, 0)``."""
    applied = ("visits", "pending_visits", "carried_visits")
    with np.load(path, allow_pickle=False) as data:
        total = sum(int(data[name].astype(np.int64).sum()) for name in applied if name in data.files)
        dropped = int(data["dropped_visits"]) if "dropped_visits" in data.files else 0
    return total, dropped


class VersionMark:
    def __init__(self, run_dir: Path) -> None:
        self.path = run_dir / VERSION_MARK

    def record(self, version: int) -> None:
        write_atomic(self.path, json.dumps({"published": version}).encode())

    def load(self) -> int:
        if not self.path.exists():
            return 0
        try:
            return int(json.loads(self.path.read_text())["published"])
        except (OSError, ValueError, KeyError) as exc:
            raise CheckpointError(f"--resume: unreadable version mark {self.path}: {exc}") from None
