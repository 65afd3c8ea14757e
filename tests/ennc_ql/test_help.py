"""Help that teaches: every command's page has a description, two examples and its typical run time; every flag
has help text and its default; values that come from a registry are offered as choices; no markup leaks."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections.abc import Iterator
from importlib.metadata import version
from pathlib import Path

import pytest

from ennc_ql.cli import build_parser
from sim import FEATURIZERS
from sim.actions import ACTION_SETS
from sim.formulation import FORMULATIONS, REWARD_NAMES, TRIAL_RULES

ENNC_QL = Path(sys.executable).with_name("ennc-ql")


def commands(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    """Every command's parser under ``parser``, subcommands included."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                yield child
                yield from commands(child)


def options(parser: argparse.ArgumentParser) -> Iterator[argparse.Action]:
    for action in parser._actions:
        if not isinstance(action, argparse._HelpAction | argparse._VersionAction | argparse._SubParsersAction):
            yield action


PARSERS = {p.prog: p for p in commands(build_parser())}


def test_every_command_is_listed() -> None:
    assert set(PARSERS) == {
        *(f"ennc-ql {name}" for name in ("eval", "up", "learner", "actor", "router", "chaos", "reproduce", "ablate")),
        "ennc-ql secure",
        "ennc-ql secure init",
        *(f"ennc-ql slurm{name}" for name in ("", " train", " run", " task")),
        "ennc-ql bench",
        *(f"ennc-ql bench {name}" for name in ("sim", "ennc", "transport", "actor", "broadcast", "phase1")),
    }


@pytest.mark.parametrize("prog", sorted(PARSERS))
def test_every_help_page_has_a_description_two_examples_and_a_run_time(prog: str) -> None:
    text = PARSERS[prog].format_help()
    assert text.startswith(f"usage: {prog} [OPTIONS]")
    description = text.split("\n\n")[1]
    assert len(description.split()) >= 12, description
    examples = text.split("examples:\n")[1].split("\n\n")[0].splitlines()
    assert len(examples) >= 2 and all(line.startswith("  ennc-ql ") and "  # " in line for line in examples)
    # The examples and the run time before the options: what a reader looks for first.
    assert re.search(r"\ntypical run time: \S.*\n\n(options|positional arguments):", text), text[:2000]
    assert text.index("examples:") < text.index("options:")
    for leak in ("``", ":mod:", ":class:", ":data:", ":func:"):
        assert leak not in text


@pytest.mark.parametrize("prog", sorted(PARSERS))
def test_every_flag_has_help_text_and_its_default(prog: str) -> None:
    parser = PARSERS[prog]
    formatter = parser._get_formatter()
    for action in options(parser):
        text = formatter._get_help_string(action) or ""
        name = "/".join(action.option_strings) or action.dest
        # Something besides the default: what the flag is for.
        assert re.sub(r"\((default: [^)]*|required)\)", "", text).strip(), f"{prog} {name} has no help"
        if action.option_strings and action.nargs != 0:  # a flag that takes a value says what it is without one
            assert "default" in text or "required" in text, f"{prog} {name}: {text!r}"


@pytest.mark.parametrize(
    ("prog", "flag", "names"),
    [
        ("ennc-ql up", "--formulation", FORMULATIONS),
        ("ennc-ql learner", "--formulation", FORMULATIONS),
        ("ennc-ql learner", "--featurizer", FEATURIZERS),
        ("ennc-ql actor", "--featurizer", FEATURIZERS),
        ("ennc-ql actor", "--reward", REWARD_NAMES),
        ("ennc-ql chaos", "--formulation", FORMULATIONS),
        ("ennc-ql actor", "--trial-rules", TRIAL_RULES),
        ("ennc-ql up", "--actor-trial-rules", TRIAL_RULES),
    ],
)
def test_registry_values_are_offered_as_choices(prog: str, flag: str, names: object) -> None:
    action = PARSERS[prog]._option_string_actions[flag]
    assert isinstance(action.metavar, str)
    offered = action.metavar.removesuffix("|none").strip("{}").split(",")
    assert offered == list(names)  # type: ignore[call-overload]


def test_ablate_names_every_registered_formulation_part() -> None:
    text = PARSERS["ennc-ql ablate"]._option_string_actions["--set"].help or ""
    for part, names in (
        ("featurizer", FEATURIZERS),
        ("reward", REWARD_NAMES),
        ("actions", ACTION_SETS),
        ("trial_rules", TRIAL_RULES),
    ):
        assert f"{part} {{{', '.join(names)}}}" in text


def test_a_flag_says_its_table_once() -> None:
    up = PARSERS["ennc-ql up"]._option_string_actions
    assert "--learner-id" in up and "--learner-learner-id" not in up
    assert up["--learner-id"].dest == "learner.learner_id"


def test_version_and_top_level_help() -> None:
    out = subprocess.run([str(ENNC_QL), "--version"], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout == f"ennc-ql {version('ennc-ql')}\n"
    text = build_parser().format_help()
    assert "first steps:\n  ennc-ql eval --policy a-cmommt" in text
    for name in (
        "eval",
        "up",
        "learner",
        "actor",
        "router",
        "secure",
        "slurm",
        "chaos",
        "reproduce",
        "ablate",
        "bench",
    ):
        assert re.search(rf"\n    {name} +\S", text), name


def examples(prog: str) -> list[str]:
    """The command lines of ``prog``'s help examples."""
    text = PARSERS[prog].format_help()
    if "examples:\n" not in text:
        return []
    lines = text.split("examples:\n")[1].split("\n\n")[0].splitlines()
    return [line.split("  # ")[0].strip() for line in lines]


@pytest.mark.parametrize("prog", sorted(PARSERS))
def test_every_help_example_is_a_command_line_the_parser_takes(prog: str, capsys: pytest.CaptureFixture[str]) -> None:
    import shlex

    for example in examples(prog):
        words = shlex.split(example)
        assert words[0] == "ennc-ql", example
        try:
            build_parser().parse_args(words[1:])
        except SystemExit as exc:  # --help and --version exit 0; bad input exits 2
            assert exc.code == 0, f"{example}: {capsys.readouterr().err}"


def test_help_lists_the_common_flags_and_help_all_every_one() -> None:
    """``up --help`` hides the learner's and actors' tuning flags behind ``--help-all``, and says so."""
    parser = PARSERS["ennc-ql up"]
    short = parser.format_help()
    assert "--duration" in short and "--formulation" in short and "--learner-phase1-n-cycles" not in short
    assert short.rstrip().endswith(
        "tuning options not shown (the learner's and actors' algorithm settings): ennc-ql up --help-all"
    )
    done = subprocess.run([str(ENNC_QL), "up", "--help-all"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "--learner-phase1-n-cycles" in done.stdout and "tuning options" not in done.stdout
    assert len(short) < len(done.stdout) / 2
