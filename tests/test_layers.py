"""The package-level import picture: every arrow runs down, never back up and never round.

``ennc_ql/`` is the command line only (flat command modules, no sub-package); the libraries (``sim/``,
``algorithm/``, ``learner/``, ``actors/``, ``protocol/``, ``monitor/``, ``tools/``) never import it; ``learner/``
and ``actors/`` never import each other; and the packages, each sub-package of ``tools/`` counted on its own, form
no import circle. Read from the source with ``ast``, so a function-local import counts as much as a top-level one.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim", "algorithm", "learner", "actors", "protocol", "monitor", "tools", "ennc_ql")
COMMAND_LINE = "ennc_ql"


def node(module: str) -> str | None:
    """The package a module counts under: its top-level package, or its sub-package of ``tools``."""
    parts = module.split(".")
    if parts[0] not in PACKAGES:
        return None
    if parts[0] == "tools" and len(parts) > 1 and (ROOT / "tools" / parts[1] / "__init__.py").exists():
        return f"tools.{parts[1]}"
    return parts[0]


def imported(path: Path) -> Iterator[str]:
    """Every module (or module.name) ``path`` imports, relative imports resolved."""
    module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
    package = module.rsplit(".", 1)[0] if path.name != "__init__.py" else module.removesuffix(".__init__")
    for stmt in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(stmt, ast.Import):
            yield from (alias.name for alias in stmt.names)
        elif isinstance(stmt, ast.ImportFrom):
            if stmt.level:
                base = package.split(".")[: len(package.split(".")) - stmt.level + 1]
                source = ".".join([*base, *([stmt.module] if stmt.module else [])])
            else:
                source = stmt.module or ""
            yield source
            yield from (f"{source}.{alias.name}" for alias in stmt.names)


def edges() -> dict[tuple[str, str], set[str]]:
    """(importing package, imported package) -> the files that import across it."""
    found: dict[tuple[str, str], set[str]] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            source = node(".".join(path.relative_to(ROOT).with_suffix("").parts))
            for target in filter(None, map(node, imported(path))):
                if source is not None and target != source:
                    found.setdefault((source, target), set()).add(str(path.relative_to(ROOT)))
    return found


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one package (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                found.append(sorted([v, *component]))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_command_line_holds_no_library() -> None:
    assert [p.parent.name for p in (ROOT / COMMAND_LINE).glob("*/__init__.py")] == []


def test_no_library_imports_the_command_line() -> None:
    up = {edge: files for edge, files in edges().items() if edge[1] == COMMAND_LINE}
    assert up == {}


def test_learner_and_actors_never_import_each_other() -> None:
    found = edges()
    assert ("learner", "actors") not in found and ("actors", "learner") not in found


def test_no_import_circle_between_packages() -> None:
    graph: dict[str, set[str]] = {}
    for source, target in edges():
        graph.setdefault(source, set()).add(target)
    assert ("tools.cluster", "tools") in edges()  # the walk sees the sub-packages apart from their parent
    assert circles(graph) == []


def test_a_circle_is_found() -> None:
    assert circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
