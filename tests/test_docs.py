"""Every reference in README.md and docs/*.md resolves inside the repository: relative links and images (with their
#anchors), and the repository paths named in code spans (``tests/e2e/test_faults.py``)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
CODE_PATH = re.compile(r"`([A-Za-z_][\w.-]*(?:/[\w.-]+)+\.(?:py|md|yaml|toml|png|json5?|txt))`")
"""A repository path in a code span: folders and a file with an extension, no placeholder (``runs/<id>/...``)."""
OUTSIDE = ("runs/", "secrets/", "/")
"""Paths a user's runs create, not the repository's."""


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as hyphens.

    >>> slug("Reproducing the paper: `ennc-ql reproduce`")
    'reproducing-the-paper-ennc-ql-reproduce'
    """
    text = heading.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.DOTALL)  # a # in a code block is no heading
    return {slug(m) for m in re.findall(r"^#{1,6} (.+)$", text, flags=re.MULTILINE)}


def outside_code_blocks(text: str) -> str:
    return re.sub(r"```.*?```", "", text, flags=re.DOTALL)


@pytest.mark.parametrize("doc", DOCS, ids=[str(p.relative_to(ROOT)) for p in DOCS])
def test_every_relative_link_resolves(doc: Path) -> None:
    missing = []
    for target in LINK.findall(outside_code_blocks(doc.read_text())):
        if re.match(r"[a-z][a-z+.-]*:", target):  # https:, mailto:: not this repository's
            continue
        path_part, _, anchor = target.partition("#")
        path = (doc.parent / path_part).resolve() if path_part else doc
        inside = path.exists() and ROOT in (path, *path.parents)
        if not inside or (anchor and path.suffix == ".md" and anchor not in anchors(path)):
            missing.append(target)
    assert missing == [], f"{doc.name}: links that do not resolve: {missing}"


@pytest.mark.parametrize("doc", DOCS, ids=[str(p.relative_to(ROOT)) for p in DOCS])
def test_every_repository_path_named_exists(doc: Path) -> None:
    named = {p for p in CODE_PATH.findall(doc.read_text()) if not p.startswith(OUTSIDE)}
    assert sorted(p for p in named if not (ROOT / p).exists()) == []


def test_the_readme_needs_nothing_outside_the_repository() -> None:
    """The design and algorithm notes a clone lacks are in docs/, in the project's words."""
    for doc in DOCS:
        text = doc.read_text()
        assert "shared/spec" not in text and "algorithms.md` §" not in text, doc.name
