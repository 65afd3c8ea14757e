"""The documentation stays true to the code: every link and repository path in README.md and docs/ resolves, every
command the README and the guide show exists with the flags they give it, the quickstart's fast commands print what
the README shows, the configuration reference is the one its generator writes, a newcomer's path stays short, and no
page or code tells the history of its making in numbered stages (the notebook, docs/notebook.md, is that history,
under dated headings).

A command shown after ``$ `` is run (``$ ennc-ql …``) or checked against the Makefile (``$ make …``), and the lines
after it are its output: each must appear, in order, with ``…`` standing for any lines left out."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tools.reference.configuration import PAGE, check

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs").rglob("*.md"))]
GUIDE = sorted((ROOT / "docs" / "guide").glob("*.md"))
CONCEPTS = sorted((ROOT / "docs" / "concepts").glob("*.md"))
NOTEBOOK = ROOT / "docs" / "notebook.md"
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
CODE_PATH = re.compile(r"`([A-Za-z_][\w.-]*(?:/[\w.-]+)+\.(?:py|md|yaml|toml|png|json5?|txt))`")
"""A repository path in a code span: folders and a file with an extension, no placeholder (``runs/<id>/...``)."""
OUTSIDE = ("runs/", "secrets/", "/")
"""Paths a user's runs create, not the repository's."""
README_LINES, NEWCOMER_LINES = 300, 1500
"""The README is a manual, and the path a newcomer walks (README, the guide, the concepts) is read in one sitting."""


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as hyphens.

    >>> slug("Reproducing the paper: `ennc-ql reproduce`")
    'reproducing-the-paper-ennc-ql-reproduce'
    """
    text = heading.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    return {slug(m) for m in re.findall(r"^#{1,6} (.+)$", outside_code_blocks(path.read_text()), flags=re.MULTILINE)}


def outside_code_blocks(text: str) -> str:
    return re.sub(r"```.*?```", "", text, flags=re.DOTALL)  # a # in a code block is no heading


def code_blocks(path: Path) -> Iterator[list[str]]:
    """The lines of each fenced code block of ``path``, continuation lines (``\\``) joined."""
    for block in re.findall(r"^```[^\n]*\n(.*?)^```", path.read_text(), flags=re.DOTALL | re.MULTILINE):
        yield block.replace("\\\n", " ").splitlines()


def ids(paths: list[Path]) -> list[str]:
    return [str(p.relative_to(ROOT)) for p in paths]


@pytest.mark.parametrize("doc", DOCS, ids=ids(DOCS))
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


@pytest.mark.parametrize("doc", DOCS, ids=ids(DOCS))
def test_every_repository_path_named_exists(doc: Path) -> None:
    named = {p for p in CODE_PATH.findall(doc.read_text()) if not p.startswith(OUTSIDE)}
    assert sorted(p for p in named if not (ROOT / p).exists()) == []


def test_the_readme_needs_nothing_outside_the_repository() -> None:
    """The design and algorithm notes a clone lacks are in docs/, in the project's words."""
    for doc in DOCS:
        text = doc.read_text()
        assert "shared/spec" not in text and "algorithms.md` §" not in text, doc.name


# Commands shown in the README and the guide.


def shown_commands(doc: Path) -> Iterator[list[str]]:
    """Every ``ennc-ql``, ``make`` and ``scripts/`` command line of ``doc``'s code blocks, as argv: in a block with
    ``$`` prompts only the prompted lines (the others are output), in any other block every line that holds one; a
    ``host:`` label and a ``# comment`` dropped, ``[optional]`` brackets and ``…`` left out."""
    for block in code_blocks(doc):
        prompted = any(line.startswith("$ ") for line in block)
        for line in block:
            if prompted and not line.startswith("$ "):
                continue
            line = re.sub(r"\s+#\s.*$", "", line.removeprefix("$ "))
            found = re.search(r"(?:^|\s|/)(ennc-ql|make|(?:\.venv/bin/)?python|\.venv/bin/pytest)\s(.*)$", line)
            if found is None:
                continue
            words = shlex.split(found[2].replace("[", " ").replace("]", " "))
            yield [found[1].removeprefix(".venv/bin/"), *(w for w in words if w not in ("…", "..."))]


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(actions[0].choices) if actions else {}


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {option for action in parser._actions for option in action.option_strings}


def unknown_in(argv: list[str], parser: argparse.ArgumentParser) -> list[str]:
    """The subcommands and flags of an ``ennc-ql`` command line that its parser does not have."""
    unknown, commands = [], _subcommands(parser)
    for word in argv:
        if commands and not word.startswith("-"):
            if word not in commands:
                return [*unknown, word]
            parser = commands[word]
            commands = _subcommands(parser)
        elif word.startswith("-") and " " not in word and word.split("=")[0] not in _options(parser):
            unknown.append(word)
    return unknown


def make_targets() -> set[str]:
    """The Makefile's targets, its variables expanded (``$(STAMP)`` is ``.venv/.installed``)."""
    text = (ROOT / "Makefile").read_text()
    variables = dict(re.findall(r"^(\w+)\s*[?:]?=\s*(\S+)", text, flags=re.MULTILINE))
    for _ in range(3):  # variables of variables
        text = re.sub(r"\$\((\w+)\)", lambda m: variables.get(m[1], m[0]), text)
    return set(re.findall(r"^([\w./-]+):", text, flags=re.MULTILINE))


@pytest.mark.parametrize("doc", [README, *GUIDE], ids=ids([README, *GUIDE]))
def test_every_command_shown_exists(doc: Path) -> None:
    """A command that a page shows parses: its subcommands and flags are the real parser's, its make target is the
    Makefile's, its script or test file exists."""
    from ennc_ql.cli import build_parser

    parser, wrong = build_parser(), []
    for argv in shown_commands(doc):
        tool, args = argv[0], argv[1:]
        if tool == "ennc-ql":
            wrong += [f"ennc-ql {' '.join(args)}: {w}" for w in unknown_in(args, parser)]
        elif tool == "make":
            wrong += [f"make {t}" for t in args if not t.startswith("-") and "=" not in t and t not in make_targets()]
        else:
            wrong += [
                f"{tool} {p}" for p in args if re.match(r"(scripts|tests|examples)/", p) and not (ROOT / p).exists()
            ]
    assert wrong == [], f"{doc.name}: commands that do not exist as shown: {wrong}"


def prompted(doc: Path) -> Iterator[tuple[str, list[str]]]:
    """Each ``$ command`` of ``doc`` with the output lines shown after it."""
    for block in code_blocks(doc):
        for i, line in enumerate(block):
            if line.startswith("$ "):
                rest = block[i + 1 :]
                end = next((k for k, later in enumerate(rest) if later.startswith("$ ")), len(rest))
                yield line.removeprefix("$ "), rest[:end]


def missing_lines(shown: list[str], printed: list[str]) -> list[str]:
    """The shown lines that the printed output lacks: runs of lines between ``…`` must appear whole and in order,
    the first run at the start.

    >>> missing_lines(["a", "…", "c", "d"], ["a", "b", "c", "d", "e"])
    []
    >>> missing_lines(["a", "c"], ["a", "b", "c"])
    ['c']
    """
    runs: list[list[str]] = [[]]
    for line in shown:
        if line.strip() == "…":
            runs.append([])
        else:
            runs[-1].append(line.rstrip())
    at, missing = 0, []
    for k, run in enumerate(r for r in runs if r):
        starts = [at] if k == 0 and runs[0] else range(at, len(printed) - len(run) + 1)
        found = next((s for s in starts if printed[s : s + len(run)] == run), None)
        if found is None:
            missing += run
        else:
            at = found + len(run)
    return missing


def _run_ennc_ql(command: str) -> list[str]:
    args = shlex.split(command)[1:]
    env = {**os.environ, "COLUMNS": "80", "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, "-m", "ennc_ql.cli", *args], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, f"{command}: exit status {done.returncode}\n{done.stderr}"
    return [line.rstrip() for line in done.stdout.splitlines()]


def _make_echoes() -> list[str]:
    """What the Makefile's ``@echo`` lines print, with ``.venv`` for ``$(VENV)``, up to a ``$$(...)`` in them."""
    makefile = (ROOT / "Makefile").read_text().replace("$(VENV)", ".venv")
    return [re.split(r"\$\$\(", line)[0] for line in re.findall(r'@echo "([^"]*)"', makefile)]


@pytest.mark.parametrize(
    ("command", "shown"),
    [pair for doc in (README, *GUIDE) for pair in prompted(doc)],
    ids=[command for doc in (README, *GUIDE) for command, _ in prompted(doc)],
)
def test_the_quickstarts_fast_commands_print_what_is_shown(command: str, shown: list[str]) -> None:
    """``$ ennc-ql …`` runs (each a few seconds) and prints the lines shown; ``$ make …`` (an install, not run here)
    shows lines the Makefile prints."""
    if command.split()[0] in ("ennc-ql", ".venv/bin/ennc-ql"):
        assert missing_lines(shown, _run_ennc_ql(command)) == [], f"{command} no longer prints what is shown"
    else:
        assert command.split()[0] == "make", f"a $ command the test cannot run: {command}"
        echoes = _make_echoes()
        lines = [line for line in shown if line.strip() != "…"]
        assert all(any(line.startswith(echo) for echo in echoes) for line in lines), f"{command}: {lines}"


# The shape of the documentation.


def test_the_readme_and_a_newcomers_path_stay_short() -> None:
    readme = len(README.read_text().splitlines())
    path = sum(len(p.read_text().splitlines()) for p in [README, *GUIDE, *CONCEPTS])
    assert readme <= README_LINES, f"README.md has {readme} lines (at most {README_LINES}): move detail to docs/"
    assert path <= NEWCOMER_LINES, f"README, guide and concepts have {path} lines (at most {NEWCOMER_LINES})"


def test_the_configuration_reference_is_the_codes() -> None:
    assert check(ROOT / PAGE) is None, check(ROOT / PAGE)


ORDINALS = (
    "first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|thirteenth|fourteenth|"
    "fifteenth|sixteenth|seventeenth|eighteenth|nineteenth|twentieth|twenty-[a-z]+|thirtieth"
)
STAGE = re.compile(rf"\b(?:{ORDINALS})\b(?:\s+[^\s.,;:]+){{0,2}}?\s+(?:round|session|stage)s?\b(?!-)", re.IGNORECASE)
"""A numbered stage of the project's history: "the seventh round", "the twenty-third session", "the third
2026-12-03 session"."""
SOURCES = ("sim", "algorithm", "learner", "actors", "protocol", "monitor", "tools", "ennc_ql")
"""The packages; tests, scripts and examples are read too."""


def told_in_stages() -> Iterator[Path]:
    """Every page and source file but the notebook and this test (which names the words it looks for)."""
    yield from (doc for doc in DOCS if doc != NOTEBOOK)
    for folder in (*SOURCES, "tests", "scripts", "examples"):
        yield from (p for p in sorted((ROOT / folder).rglob("*.py")) if p != Path(__file__).resolve())
    yield from (
        ROOT / name for name in ("Makefile", "compose.yaml", "compose.secure.yaml", "Dockerfile", "pyproject.toml")
    )


def test_nothing_but_the_notebook_tells_the_history_in_numbered_stages() -> None:
    found = [
        f"{path.relative_to(ROOT)}:{n}: {match[0]}"
        for path in told_in_stages()
        if path.exists()
        for n, line in enumerate(path.read_text().splitlines(), 1)
        for match in [STAGE.search(line)]
        if match
    ]
    why = "cite the notebook by its entry's date and topic, or say the reason itself"
    assert found == [], why + ":\n" + "\n".join(found)


def test_the_notebooks_headings_are_dates_and_topics_in_order() -> None:
    headings = re.findall(r"^(#{2,6}) (.+)$", outside_code_blocks(NOTEBOOK.read_text()), flags=re.MULTILINE)
    assert headings, "no entries"
    assert all(level == "##" and re.fullmatch(r"\d{4}-\d{2}-\d{2}: \S.*", text) for level, text in headings), [
        text for level, text in headings if level != "##" or not re.fullmatch(r"\d{4}-\d{2}-\d{2}: \S.*", text)
    ]
    dates = [text[:10] for _, text in headings]
    assert dates == sorted(dates), "entries are appended in date order"
