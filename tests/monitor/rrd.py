"""Reading test recordings back, beyond what ``monitor.summarize_recording`` reports."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rerun.chunk import RrdReader


def rows(path: Path, entity: str, column: str, index: str) -> list[tuple[int, Any]]:
    """(index value, column value) of every non-static row of ``entity``, sorted by the ``index`` timeline."""
    found: list[tuple[int, Any]] = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == f"/{entity}" and not chunk.is_static:
            batch = chunk.to_record_batch()
            found += zip(batch.column(index).to_pylist(), batch.column(column).to_pylist(), strict=True)
    return sorted(found, key=lambda row: row[0])


def blueprint(path: Path) -> tuple[dict[str, tuple[str, str]], str]:
    """The views of the file's blueprint, name -> (view class, origin), and the time panel's timeline."""
    reader = RrdReader(path)
    (store,) = reader.blueprints()
    views: dict[str, tuple[str, str]] = {}
    timeline = ""
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if "ViewBlueprint:space_origin" in names:
            (name,) = batch.column("ViewBlueprint:display_name").to_pylist()[0]
            (kind,) = batch.column("ViewBlueprint:class_identifier").to_pylist()[0]
            (origin,) = batch.column("ViewBlueprint:space_origin").to_pylist()[0]
            views[name] = (kind, origin)
        if "TimePanelBlueprint:timeline" in names:
            (timeline,) = batch.column("TimePanelBlueprint:timeline").to_pylist()[0]
    return views, timeline
