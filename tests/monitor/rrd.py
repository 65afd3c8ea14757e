"""Reading test recordings back, beyond what ``monitor.summarize_recording`` reports."""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa
from rerun.chunk import RrdReader


def rows(path: Path, entity: str, column: str, index: str) -> list[tuple[int, Any]]:
    """(index value, column value) of every non-static row of ``entity``, sorted by the ``index`` timeline (a
    duration timeline, such as ``train_time``, in nanoseconds)."""
    found: list[tuple[int, Any]] = []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == f"/{entity}" and not chunk.is_static:
            batch = chunk.to_record_batch()
            times = batch.column(index)
            if pa.types.is_duration(times.type):
                times = times.cast(pa.int64())
            found += zip(times.to_pylist(), batch.column(column).to_pylist(), strict=True)
    return sorted(found, key=lambda row: row[0])


@dataclass
class View:
    """One view of a blueprint as the viewer receives it."""

    name: str
    kind: str
    origin: str
    contents: list[str]
    properties: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Property archetype (``TimeAxis``, ``PlotLegend``, ``VisualBounds2D``, ...) -> its fields."""
    overrides: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Entity path -> the visualizer and the fields its override sets (``SeriesLines:colors``, ...)."""


@dataclass
class Layout:
    """The last blueprint of a file, its views in layout order (depth first from the root container)."""

    views: list[View]
    containers: dict[str, list[str]]
    """Container name -> the names of its children, in order (unnamed containers are left out)."""
    time_panel: dict[str, Any]


def _cell(column: pa.Array) -> Any:
    """A blueprint component's value: unions (a time range's boundaries) give the name of their variant."""
    if pa.types.is_list(column.type):
        column = column.flatten()
    if pa.types.is_struct(column.type) and any(pa.types.is_union(f.type) for f in column.type):
        return {
            f.name: f.type.field(f.type.type_codes.index(column.field(f.name).type_codes[0].as_py())).name
            for f in column.type
        }
    values = column.to_pylist()
    return values[0] if len(values) == 1 else values


def _blueprint_rows(path: Path) -> dict[str, dict[str, Any]]:
    """Entity path (without the leading ``/``) -> component column -> its latest value in the blueprint store."""
    reader = RrdReader(path)
    (store,) = reader.blueprints()
    latest: dict[str, dict[str, tuple[int, Any]]] = {}
    for chunk in reader.stream(store=store):
        batch = chunk.to_record_batch()
        when = batch.column("blueprint").to_pylist() if "blueprint" in batch.schema.names else [0] * batch.num_rows
        fields = latest.setdefault(chunk.entity_path.lstrip("/"), {})
        for name in batch.schema.names:
            if ":" not in name:
                continue
            for row in range(batch.num_rows):
                cell = batch.column(name).slice(row, 1)
                if cell.null_count == 0 and (name not in fields or fields[name][0] <= when[row]):
                    fields[name] = (when[row], _cell(cell))
    return {entity: {name: value for name, (_, value) in fields.items()} for entity, fields in latest.items()}


def _view(rows: dict[str, dict[str, Any]], entity: str) -> View:
    fields = rows[entity]
    query = rows.get(f"{entity}/ViewContents", {}).get("ViewContents:query", [])
    view = View(
        name=fields["ViewBlueprint:display_name"],
        kind=fields["ViewBlueprint:class_identifier"],
        origin=fields["ViewBlueprint:space_origin"],
        contents=[query] if isinstance(query, str) else query,
    )
    overrides = f"{entity}/ViewContents/overrides/"
    for path, values in rows.items():
        if path.startswith(overrides) and "/visualizers/" in path:
            target = path.removeprefix(overrides).split("/visualizers/")[0]
            view.overrides.setdefault(target, {}).update(values)
        elif path.startswith(f"{entity}/") and path.count("/") == entity.count("/") + 1:
            prop = path.rsplit("/", 1)[1]
            if prop != "ViewContents":
                view.properties[prop] = {name.split(":", 1)[1]: value for name, value in values.items()}
    return view


def layout(path: Path) -> Layout:
    """The blueprint the file ends with, as the viewer lays it out."""
    rows = _blueprint_rows(path)
    found = Layout(views=[], containers={}, time_panel=rows.get("time_panel", {}))

    def visit(entity: str) -> str:
        fields = rows[entity]
        if entity.startswith("view/"):
            found.views.append(_view(rows, entity))
            return found.views[-1].name
        children = fields["ContainerBlueprint:contents"]
        names = [visit(child) for child in ([children] if isinstance(children, str) else children)]
        name = fields.get("ContainerBlueprint:display_name", "")
        if name:
            found.containers[name] = names
        return name

    visit(f"container/{uuid.UUID(bytes=bytes(rows['viewport']['ViewportBlueprint:root_container']))}")
    return found
