"""Recording files: merging the part files of a run into one, and reading a file back to see what it holds."""

from __future__ import annotations

import importlib.util
import logging
import os
import shutil
import subprocess
import sys
import warnings
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


class RecordingError(RuntimeError):
    """The Rerun CLI is missing or failed on a recording file."""


def rerun_cli() -> list[str]:
    """The command that runs the ``rerun`` CLI of the installed rerun-sdk.

    Tried in order: the ``rerun`` script next to ``sys.executable`` (a venv's bin/), ``python -m rerun_cli`` (the
    binary bundled with the SDK; lighter than ``-m rerun``, which imports the SDK first), then ``rerun`` on PATH.
    The bundled CLI comes before PATH because it matches the SDK version that wrote the files.
    """
    beside = Path(sys.executable).parent / "rerun"
    if beside.is_file():
        return [str(beside)]
    if importlib.util.find_spec("rerun_cli") is not None:
        return [sys.executable, "-m", "rerun_cli"]
    on_path = shutil.which("rerun")
    if on_path is not None:
        return [on_path]
    raise RecordingError("no rerun CLI found: install rerun-sdk (it bundles the `rerun` executable)")


def merge_recordings(parts: Sequence[Path], out: Path) -> Path:
    """Merge the .rrd ``parts`` into ``out`` with ``rerun rrd merge``; returns ``out``.

    Parts with the same application and recording id become one recording (a part cut short by a killed process
    merges up to its last flushed chunk). Raises :class:`RecordingError` when the CLI fails, FileNotFoundError when
    a part is missing.
    """
    if not parts:
        raise ValueError("merge_recordings needs at least one part file")
    missing = [str(p) for p in parts if not Path(p).is_file()]
    if missing:
        raise FileNotFoundError(f"recording part file(s) not found: {', '.join(missing)}")
    if any(Path(p).resolve() == out.resolve() for p in parts):
        raise ValueError(f"the merged file {out} is also one of the parts")
    out.parent.mkdir(parents=True, exist_ok=True)
    command = [*rerun_cli(), "rrd", "merge", "-o", str(out), *(str(p) for p in parts)]
    # NO_COLOR keeps the CLI's log lines free of terminal escapes in the error message below.
    done = subprocess.run(command, capture_output=True, text=True, check=False, env={**os.environ, "NO_COLOR": "1"})
    if done.returncode != 0:
        raise RecordingError(
            f"`rerun rrd merge` exited with {done.returncode} merging {len(parts)} file(s) into {out}: "
            f"{done.stderr.strip()[-2000:]}"
        )
    log.info("merged %d recording part(s) into %s (%d bytes)", len(parts), out, out.stat().st_size)
    return out


def summarize_recording(path: Path) -> dict[str, Any]:
    """What an .rrd file holds, read back with ``rerun.chunk.RrdReader``.

    Keys: ``path``, ``size_bytes``; ``recording_ids`` and ``application_ids`` (sorted distinct, over the
    recording stores), ``blueprints`` (number of blueprint stores); over the recording stores' chunks:
    ``entity_paths`` (sorted, without the leading ``/``), ``chunks``, ``rows``, ``rows_per_entity`` (rows logged
    on a timeline, i.e. not static, per entity path) and ``timelines`` (sorted).
    """
    from rerun.chunk import RrdReader

    path = Path(path)
    with warnings.catch_warnings():
        # Files without a footer (a process killed while saving) warn; stream() below reads them fully anyway.
        warnings.filterwarnings("ignore", message="RRD file has no footer")
        reader = RrdReader(path)
        recordings = reader.recordings()
        blueprints = reader.blueprints()
    entities: set[str] = set()
    timelines: set[str] = set()
    rows_per_entity: Counter[str] = Counter()
    chunks = rows = 0
    for store in recordings:
        for chunk in reader.stream(store=store):
            entity = chunk.entity_path.lstrip("/")
            entities.add(entity)
            timelines.update(chunk.timeline_names)
            chunks += 1
            rows += chunk.num_rows
            if not chunk.is_static:
                rows_per_entity[entity] += chunk.num_rows
    return {
        "path": str(path),
        "size_bytes": path.stat().st_size,
        "recording_ids": sorted({s.recording_id for s in recordings}),
        "application_ids": sorted({s.application_id for s in recordings}),
        "blueprints": len(blueprints),
        "entity_paths": sorted(entities),
        "chunks": chunks,
        "rows": rows,
        "rows_per_entity": dict(sorted(rows_per_entity.items())),
        "timelines": sorted(timelines),
    }
