"""The configuration reference, ``docs/reference/configuration.md``, written from the configuration dataclasses:
every field's TOML key, flag, type and default, and its docstring, the same text ``--help`` shows. The page is
generated, never edited, so it says what the code does::

    text = render()                   # the page as docs/reference/configuration.md holds it
    stale = check(ROOT / PAGE)        # None, or what to run to write it again

``scripts/config_reference.py`` writes it; ``tests/test_docs.py`` fails when the page and the code differ.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from actors.config import ActorConfig
from learner.config import LearnerConfig
from tools.cluster import SET_BY_UP, UP_PRESETS, UpConfig
from tools.config_fields import Leaf, config_leaves, flag_name, metavar, show
from tools.slurm.array import ArrayConfig
from tools.slurm.job import SlurmJob
from tools.sweeps.ablate import Setup

PAGE = Path("docs/reference/configuration.md")
"""Where the page lives, from the repository root."""
ROOT = Path(__file__).resolve().parents[2]
"""The repository root (the page is written into the source tree, never into an installed copy)."""
COMMAND = ".venv/bin/python scripts/config_reference.py"
"""What writes the page again."""


@dataclass(frozen=True, slots=True)
class Section:
    """One configuration class on the page."""

    title: str
    cls: type
    intro: str
    prefix: str = ""
    """The class's path inside ``up``'s configuration (``learner.``), for the column of ``up``'s flags; empty: none."""
    flags: bool = True
    """Its fields are flags of a command (else only ``--set`` or file keys)."""


SECTIONS = (
    Section(
        "ennc-ql up (and chaos)",
        UpConfig,
        "`tools.cluster.UpConfig`: a local run, `up.toml` of a run folder, and the cluster of `ennc-ql chaos` (which "
        "takes every flag but `--duration`, its own). Its `[learner]` and `[actor]` tables are the two sections "
        "below, whose last columns give `up`'s flag and default for each field; the other fields are:",
    ),
    Section(
        "ennc-ql learner, and up's [learner]",
        LearnerConfig,
        "`learner.config.LearnerConfig`, with ENNC-QL phase 1 (`algorithm.phase1.Phase1Config`) as `phase1`. "
        "`ennc-ql learner --config FILE` reads these keys; in `up.toml` they are the `[learner]` table. `up` "
        "presets some (`tools.cluster.UP_PRESETS`) and sets the ones marked *set by up* itself.",
        prefix="learner.",
    ),
    Section(
        "ennc-ql actor, and up's [actor]",
        ActorConfig,
        "`actors.config.ActorConfig`, with phase 2 (`algorithm.agent.Phase2Config`) as `phase2`. `ennc-ql actor "
        "--config FILE` reads these keys; in `up.toml` they are the `[actor]` table, given to every actor.",
        prefix="actor.",
    ),
    Section(
        "ennc-ql slurm train",
        SlurmJob,
        "`tools.slurm.job.SlurmJob`: the job's own settings, beside `up`'s run configuration (above), which `slurm "
        "train` takes as `up` does; written to the run folder's `slurm.toml`.",
    ),
    Section(
        "ennc-ql ablate / reproduce --slurm",
        ArrayConfig,
        "`tools.slurm.array.ArrayConfig`: a sweep's learning processes as one SLURM job array.",
    ),
    Section(
        "ennc-ql ablate --set",
        Setup,
        "`tools.sweeps.ablate.Setup`: everything a variant of a sweep may change, by dotted key (`--set "
        "budget.phase2.alpha=0.05,0.1`): the learning budget (`algorithm.experiments.Budget`), the scenario "
        "(`sim.config.ScenarioConfig`, the world of every command; its fields carry their provenance: [paper], "
        "[public] or [choice]) and the formulation's parts.",
        flags=False,
    ),
)


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _code(text: str) -> str:
    return f"`{text}`" if text else ""


def _rows(section: Section, up: Mapping[str, Leaf]) -> Iterable[str]:
    leaves = config_leaves(section.cls)
    if section.cls is UpConfig:  # its learner and actor tables have sections of their own
        leaves = [leaf for leaf in leaves if not leaf.path.startswith(("learner.", "actor."))]
    header = [
        "key",
        *(["flag"] if section.flags else []),
        "type",
        "default",
        *(["`up`'s flag", "`up`'s default"] if section.prefix else []),
        "what it is",
    ]
    yield "| " + " | ".join(header) + " |"
    yield "|" + "---|" * len(header)
    for leaf in leaves:
        default = "required" if leaf.default is dataclasses.MISSING else show(leaf, leaf.default)
        cells = [_code(leaf.path), *([_code(flag_name(leaf.path))] if section.flags else [])]
        cells += [_code(metavar(leaf)), _code(default)]
        if section.prefix:
            path = section.prefix + leaf.path
            if any(path == p or path.startswith(p + ".") for p in SET_BY_UP):
                cells += ["*set by up*", ""]
            else:
                preset = show(up[path], UP_PRESETS.get(path, up[path].default))
                cells += [_code(flag_name(path)), "" if preset == default else _code(preset)]
        cells.append(leaf.doc)
        yield "| " + " | ".join(_cell(c) for c in cells) + " |"


def render() -> str:
    """The page."""
    up = {leaf.path: leaf for leaf in config_leaves(UpConfig)}
    lines = [
        "# Configuration reference",
        "",
        f"<!-- Generated by {COMMAND} from the configuration dataclasses; edit their docstrings, not this page. -->",
        "",
        "Every setting of every process, as its configuration dataclass defines it: the TOML key (`--config FILE`, "
        "and the files a run writes), the flag, the type, the default and the field's docstring, which is also its "
        "`--help` text. A flag given overrides the file; an unknown key, a value of the wrong type or out of range is "
        "a one-line error before anything starts. `none` spells None, on the command line and in a file. How the "
        "commands use them: [the guide](../guide/running.md#training-runs).",
        "",
    ]
    for section in SECTIONS:
        lines += [f"## {section.title}", "", section.intro, "", *_rows(section, up), ""]
    return "\n".join(lines)


def check(page: Path) -> str | None:
    """None when ``page`` is what :func:`render` writes; else the command that writes it again."""
    current = page.read_text() if page.exists() else ""
    return None if current == render() else f"{page} is out of date: run {COMMAND}"


def write(page: Path) -> Path:
    page.write_text(render())
    return page
