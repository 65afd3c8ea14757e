"""The argparse machinery of every ``ennc-ql`` command: one error contract, and help pages that teach.

The contract (after clap, as in ``rerun`` and ``zenohd``): bad input is one line on stderr, ``ennc-ql <command>:
error: <what is wrong>``, then at most one line of short usage, and exit status 2, before anything starts. The
command that was given answers for its own flags (an unknown flag of ``up`` is ``up``'s error, with the closest
flag it has), and argparse's own wording is turned into the same style. A command's help page carries a description,
two examples and its typical run time (:class:`CommandHelp`). Usage::

    parser = CommandParser(prog="ennc-ql")
    sub = add_commands(parser, dest="command")
    p = add_command(sub, CommandHelp("eval", "score a policy", "Scores ...", (("ennc-ql eval", "A-CMOMMT"),), "1 s"))
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import os
import re
import shutil
import sys
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NoReturn

from tools.config_fields import plain

if TYPE_CHECKING:
    from _typeshed import SupportsWrite

PROG = "ennc-ql"


def wrap(text: str) -> str:
    """Paragraphs (blank-line separated) wrapped to the terminal, at most 100 columns, as argparse wraps help."""
    width = min(shutil.get_terminal_size().columns, 102) - 2
    return "\n\n".join(textwrap.fill(" ".join(p.split()), width) for p in text.split("\n\n"))


def suggestion(word: str, known: Sequence[str]) -> str:
    """``"; did you mean 'x'?"`` for the closest of ``known``, or nothing.

    >>> suggestion("--durtion", ["--duration", "--seed"])
    "; did you mean '--duration'?"
    """
    close = difflib.get_close_matches(word, list(known), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


class OutputError(Exception):
    """Standard output refused what a command printed (a full disk, ``> /dev/full``, an I/O error): the command line
    answers it with one line on stderr and exit status 1."""

    prog: str | None = None
    """The command whose help page could not be printed, where it was one."""


def flush_out() -> None:
    """Standard output flushed; a failure is an :class:`OutputError`, except a reader that went away
    (``BrokenPipeError``), which ends the command quietly."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise _refused(exc) from exc


def say(text: str, end: str = "\n") -> None:
    """``text`` on standard output, flushed at once (:func:`flush_out`): a failure to write it is never taken for
    one of the command's own."""
    try:
        sys.stdout.write(text + end)
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise _refused(exc) from exc
    flush_out()


def _refused(exc: OSError) -> OutputError:
    """The :class:`OutputError` of ``exc``, with standard output moved onto /dev/null: what it refused stays in its
    buffer, and no later flush (the command line's last, the interpreter's at exit) may fail on it again."""
    with contextlib.suppress(OSError, ValueError):  # not a file (a test's captured output): nothing to move
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    return OutputError(exc.strerror or str(exc))


@dataclass(frozen=True, slots=True)
class CommandHelp:
    """What a command's help page teaches besides its flags."""

    name: str
    summary: str
    """One line, in the list of commands."""
    description: str
    """What it does and what it writes, a paragraph or two."""
    examples: tuple[tuple[str, str], ...]
    """(command line, what it does), two or more."""
    runtime: str
    """How long it typically takes, measured or derived from its defaults (the README's table of commands)."""

    def epilog(self) -> str:
        width = max(len(line) for line, _ in self.examples)
        lines = [f"  {line:<{width}}  # {what}" for line, what in self.examples]
        return "examples:\n" + "\n".join(lines) + f"\n\ntypical run time: {self.runtime}"


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples as written; each flag's default appended where its help does not state it."""

    def __init__(self, prog: str) -> None:
        super().__init__(prog, max_help_position=32)

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        empty = isinstance(default, str | list | tuple) and not default
        unset = default is None or default is False or default == argparse.SUPPRESS
        if "default" in text or empty or unset or not action.option_strings:
            return text
        if isinstance(default, list | tuple):
            default = " ".join(str(v) for v in default)
        return f"{text} (default: {str(default).replace('%', '%%')})"


class CommandParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors follow the contract above; subcommand parsers are of the same class."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        # Abbreviated flags would make a typo of one flag silently another (--learner-min and --learner-min-tuples).
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        if self._subparsers is not None:
            # Before the command, only this parser's flags: argparse would miss the command first, and answer
            # ``ennc-ql --bogus`` with "which command?" instead of naming the flag.
            for word in sys.argv[1:] if args is None else args:
                if not word.startswith("-") or word == "--":
                    break
                if not self._knows(word):
                    self.error(self._unrecognized([word]))
        parsed, extras = super().parse_known_args(args, namespace)
        if extras and self._subparsers is None:
            # A command without subcommands answers for words it does not know; argparse would leave them to the
            # top-level parser, which knows neither the command nor its flags.
            self.error(self._unrecognized(extras))
        return parsed, extras

    def _knows(self, word: str) -> bool:
        """Whether ``word`` is one of this parser's flags (``--flag=value`` and ``-vh`` as argparse reads them)."""
        flags = self._option_string_actions
        return word.split("=", 1)[0] in flags or (not word.startswith("--") and word[:2] in flags)

    def _print_message(self, message: str, file: SupportsWrite[str] | None = None) -> None:
        # argparse drops a failed write in silence: ``ennc-ql --help > /dev/full`` would print nothing and exit 0.
        if message and file is sys.stdout:
            try:
                say(message, end="")
            except OutputError as exc:
                exc.prog = self.prog
                raise
        else:
            super()._print_message(message, file)

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {self._reword(message)}\n{self.short_usage()}\n")
        raise SystemExit(2)

    show_all = False
    """Whether the help lists the tuning options too (``--help-all``)."""

    def format_help(self) -> str:
        # The generated usage of a command with 60 flags is a block of 40 lines; they are listed below it anyway.
        if self.usage is None:
            self.usage = self._synopsis()
        tuning = [] if self.show_all else [a for a in self._actions if is_tuning(a)]
        helps = [a.help for a in tuning]
        for action in tuning:
            action.help = argparse.SUPPRESS
        try:
            text = super().format_help()
        finally:
            for action, help_text in zip(tuning, helps, strict=True):
                action.help = help_text
        if tuning:
            hidden = f"{len(tuning)} tuning options not shown (the learner's and actors' algorithm settings)"
            text += f"\n{hidden}: {self.prog} --help-all\n"
        return text

    def short_usage(self) -> str:
        """One line: the command, ``[OPTIONS]`` and its positional arguments, and where the full list is."""
        return f"usage: {self._synopsis()}  (all options: {self.prog} --help)"

    def _synopsis(self) -> str:
        words = [self.prog, "[OPTIONS]"]
        for action in self._actions:
            if action.option_strings or action.help == argparse.SUPPRESS:
                continue
            if isinstance(action, argparse._SubParsersAction):
                words.append("COMMAND")
            else:
                name = action.metavar if isinstance(action.metavar, str) else action.dest.upper()
                words.append(f"{name} ..." if action.nargs in ("+", "*") else name)
        return " ".join(words)

    def _commands(self) -> list[str]:
        action = next(a for a in self._actions if isinstance(a, argparse._SubParsersAction))
        return list(action.choices)

    def _unrecognized(self, extras: Sequence[str]) -> str:
        word = extras[0]
        if word.startswith("-"):
            flag = word.split("=", 1)[0]
            # Matched without their dashes, which every flag shares: '--bogus' is then nothing like '--verbose'.
            names = {known.lstrip("-"): known for known in self._option_string_actions}
            close = difflib.get_close_matches(flag.lstrip("-"), list(names), n=1, cutoff=0.6)
            return f"unknown option {flag!r}" + (f"; did you mean {names[close[0]]!r}?" if close else "")
        if self._subparsers is not None:
            return f"unknown command {word!r}{suggestion(word, self._commands())}"
        return f"unexpected argument {word!r}"

    def _reword(self, message: str) -> str:
        """argparse's wording in the contract's: flags named first, choices with the closest one."""
        if message.startswith("unrecognized arguments: "):
            return self._unrecognized(message.removeprefix("unrecognized arguments: ").split())
        if message.startswith("the following arguments are required: "):
            missing = message.removeprefix("the following arguments are required: ")
            if self._subparsers is not None and missing.split(", ")[0] == "COMMAND":
                return f"which command? one of {', '.join(self._commands())}"
            return f"missing {missing}"
        choice = re.fullmatch(r"argument (\S+?): invalid choice: '(.*)' \(choose from (.*)\)", message, re.DOTALL)
        if choice:
            name, value, listed = choice.groups()
            known = [c.strip("'") for c in listed.split(", ")]
            if name == "COMMAND":
                return f"unknown command {value!r}{suggestion(value, known)} (one of {', '.join(known)})"
            return f"{name}: unknown value {value!r}{suggestion(value, known)} (one of {', '.join(known)})"
        message = re.sub(r"^argument (\S+): ", r"\1: ", message)
        return message.replace("expected one argument", "needs a value")


def is_tuning(action: argparse.Action) -> bool:
    """A flag of a nested configuration table (``--learner-phase1-n-cycles``, ``--actor-phase2-alpha``): its field
    path has a dot. A command's help lists them only with ``--help-all``."""
    return bool(action.option_strings) and "." in (action.dest or "")


class _HelpAll(argparse.Action):
    """``--help-all``: the help page with every option, the tuning ones included."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest=dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> NoReturn:
        assert isinstance(parser, CommandParser)
        parser.show_all = True
        parser.print_help()
        parser.exit()


def add_commands(parser: argparse.ArgumentParser, dest: str, title: str = "commands") -> Any:
    """The subcommand list of ``parser`` (its subparsers action), required and named COMMAND in messages; the
    name given is stored as ``dest``."""
    return parser.add_subparsers(dest=dest, metavar="COMMAND", title=title, required=True)


def add_command(sub: Any, info: CommandHelp) -> CommandParser:
    """A command's parser on ``sub`` (from :func:`add_commands`), with its description, examples and run time."""
    # The examples come right after the description, before the options: what a reader looks for first.
    parser: CommandParser = sub.add_parser(
        info.name, help=info.summary, description=wrap(plain(info.description)) + "\n\n" + info.epilog()
    )
    parser.add_argument("--help-all", action=_HelpAll, help="show every option, the tuning ones included, and exit")
    parser.set_defaults(prog=parser.prog)  # the name errors are reported under, for main's last-resort message
    return parser
