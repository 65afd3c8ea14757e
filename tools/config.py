"""Config dataclasses as command-line flags and TOML files.

A process's configuration is a frozen dataclass whose attribute docstrings are its ``--help`` text (CleanRL's
``Args``). ``add_config_flags`` gives it one flag per field, ``load_config`` builds it from, in increasing priority,
the dataclass defaults, a command's presets, a TOML file and the flags given, and ``dump_config`` writes it back::

    >>> import argparse
    >>> from dataclasses import dataclass, field
    >>> @dataclass(frozen=True)
    ... class Fit:
    ...     n_cycles: int = 250
    ...     max_patterns: int | None = 30_000
    >>> @dataclass(frozen=True)
    ... class Learner:
    ...     store_capacity: int = 1_000_000
    ...     duration: float | None = None
    ...     fit: Fit = field(default_factory=Fit)
    >>> preset = {"store_capacity": 400_000}
    >>> parser = argparse.ArgumentParser()
    >>> add_config_flags(parser, Learner, defaults=preset)
    >>> args = parser.parse_args(["--fit-n-cycles", "10", "--fit-max-patterns", "none", "--duration", "60"])
    >>> config = load_config(Learner, args=args, defaults=preset)
    >>> config
    Learner(store_capacity=400000, duration=60.0, fit=Fit(n_cycles=10, max_patterns=None))
    >>> print(dump_config(config), end="")
    store_capacity = 400000
    duration = 60.0
    <BLANKLINE>
    [fit]
    n_cycles = 10
    max_patterns = "none"

Supported field types: ``int``, ``float``, ``str``, ``bool``, ``Path``, ``Literal[...]``, ``tuple[X, ...]`` of
those, any of them ``| None``, nested dataclasses (flags ``--<field>-<subfield>``, TOML tables), and any other type
through ``field(metadata={"parse": fn})`` (``fn(str) -> value``, raising ``ValueError``; optional ``"format"``:
``fn(value) -> str`` for the TOML file and the help, default ``str``; optional ``"metavar"``). None is spelled
``none`` (any case) on the command line and in the file; a file leaves out a None whose default is None anyway.
Flags store under the field path (``args.store_capacity``, ``getattr(args, "fit.n_cycles")``), and only when given.
"""

import argparse
import dataclasses
import math
import os
import typing
from collections.abc import Callable, Collection, Iterable, Mapping
from pathlib import Path
from typing import Any, Protocol, TypeVar

import tomli_w

from tools.config_fields import (
    ConfigError,
    build,
    check_paths,
    coerce,
    config_leaves,
    field_docs,
    flag_name,
    flag_type,
    metavar,
    read_file,
    show,
    suggest,
    toml_table,
)

__all__ = [
    "ConfigError",
    "add_config_flags",
    "dump_config",
    "field_docs",
    "file_path",
    "load_config",
    "non_negative",
    "parse_setting",
    "positive",
    "replace_setting",
    "too_long",
]

T = TypeVar("T")
N = TypeVar("N", int, float)


class _AddsArguments(Protocol):  # an ArgumentParser or an argument group
    def add_argument(self, *args: Any, **kwargs: Any) -> Any: ...


def _limit(name: str, fallback: int) -> int:
    # The root's file system stands for the others: Linux's common ones (ext4, xfs, btrfs, tmpfs) all take 255.
    try:
        return os.pathconf("/", name)
    except (OSError, ValueError):
        return fallback


def too_long(text: str) -> str | None:
    """Why no file can have the path ``text``, or None: it, or a name in it, is longer than the system takes. Every
    call on such a path fails with ENAMETOOLONG, even one that only asks whether it exists.

    >>> too_long("runs/" + "x" * 300)
    "a name in it is 300 bytes long, more than the 255 a file name may have ('xxxxxxxxxxxxxxxxxxxx...')"
    """
    raw = os.fsencode(text)
    longest = max(raw.split(b"/"), key=len)
    most = _limit("PC_NAME_MAX", 255)
    if len(longest) > most:
        start = os.fsdecode(longest[:20]) + "..."
        return f"a name in it is {len(longest)} bytes long, more than the {most} a file name may have ({start!r})"
    most = _limit("PC_PATH_MAX", 4096) - 1  # the limit counts the terminating NUL
    if len(raw) > most:
        return f"it is {len(raw)} bytes long, more than the {most} a path may have"
    return None


def _path(text: str, noun: str) -> Path:
    if not text.strip():
        raise argparse.ArgumentTypeError(f"expected {noun}, got an empty value")
    problem = too_long(text)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return Path(text)


def folder(text: str) -> Path:
    """The argparse ``type`` of a folder: an empty value is an error, not the current folder (which ``Path("")`` is),
    and so is a path no folder can have (:func:`too_long`).

    >>> folder("runs/x")
    PosixPath('runs/x')
    """
    return _path(text, "a folder")


def file_path(text: str) -> Path:
    """The argparse ``type`` of a file to read: an empty value is an error (``Path("")`` is the current folder), and
    so is a path no file can have (:func:`too_long`).

    >>> file_path("runs/x/up.toml")
    PosixPath('runs/x/up.toml')
    """
    return _path(text, "a file")


def positive(kind: type[N], most: N | None = None, why: str = "") -> Callable[[str], N]:
    """The argparse ``type`` of a positive number: ``positive(int)`` or ``positive(float)``; with ``most``, one of at
    most that (``why`` says why, in the message).

    >>> positive(int)("3"), positive(float)("0.5"), positive(int, most=10)("10")
    (3, 0.5, 10)
    """
    noun = "integer" if kind is int else "finite number"
    bound = "" if most is None else f" of at most {most}{why}"

    def parse(text: str) -> N:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {noun}{bound}, got {text!r}") from None
        if not 0 < value < math.inf or (most is not None and value > most):  # also rejects nan
            raise argparse.ArgumentTypeError(f"expected a positive {noun}{bound}, got {text!r}")
        return value

    parse.__name__ = f"positive_{kind.__name__}"
    return parse


def non_negative(kind: type[N]) -> Callable[[str], N]:
    """The argparse ``type`` of a number that is 0 or more (a seed, an index).

    >>> non_negative(int)("0")
    0
    """
    noun = "an integer" if kind is int else "a finite number"

    def parse(text: str) -> N:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun} of 0 or more, got {text!r}") from None
        if not 0 <= value < math.inf:
            raise argparse.ArgumentTypeError(f"expected {noun} of 0 or more, got {text!r}")
        return value

    parse.__name__ = f"non_negative_{kind.__name__}"
    return parse


def add_config_flags(
    parser: _AddsArguments,
    cls: type,
    *,
    exclude: Iterable[str] = (),
    defaults: Mapping[str, Any] | None = None,
    choices: Mapping[str, Collection[str]] | None = None,
) -> None:
    """One flag per field of ``cls``: ``store_capacity`` -> ``--store-capacity``, ``phase1.n_cycles`` ->
    ``--phase1-n-cycles`` (a field that repeats its table's name says it once: ``learner.learner_id`` ->
    ``--learner-id``); bools get ``--x/--no-x``. ``exclude`` names field paths (a nested field's path drops all of
    it); ``defaults`` are the command's presets by field path, shown as the default in the help; ``choices`` lists
    the values a text field takes, by field name, wherever it is nested (``{"formulation": FORMULATIONS}``).

    A flag sets its attribute, named by the field path (``getattr(args, "phase1.n_cycles")``), only when given, so
    ``load_config`` can rank it above the file.
    """
    leaves, excluded = config_leaves(cls), tuple(exclude)
    check_paths(cls, leaves, excluded, "exclude", tables=True)
    check_paths(cls, leaves, defaults or {}, "defaults", tables=False)
    for leaf in leaves:
        if any(leaf.path == e or leaf.path.startswith(e + ".") for e in excluded):
            continue
        default = (defaults or {}).get(leaf.path, leaf.default)
        shown = "required" if default is dataclasses.MISSING else f"default: {show(leaf, default)}"
        help_text = f"{leaf.doc} ({shown})" if leaf.doc else f"({shown})"
        allowed = (choices or {}).get(leaf.path.rsplit(".", 1)[-1])
        common = {"dest": leaf.path, "default": argparse.SUPPRESS, "help": help_text.replace("%", "%%")}
        if leaf.kind is bool and not leaf.optional and "parse" not in leaf.metadata:
            parser.add_argument(flag_name(leaf.path), action=argparse.BooleanOptionalAction, **common)
        else:
            parser.add_argument(
                flag_name(leaf.path), type=flag_type(leaf, allowed), metavar=metavar(leaf, allowed), **common
            )


def load_config(
    cls: type[T],
    *,
    file: str | Path | None = None,
    args: argparse.Namespace | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> T:
    """``cls`` built from its defaults < ``defaults`` (presets by field path) < the TOML ``file`` < the flags
    given in ``args`` (from a parser with ``add_config_flags``). Raises ``ConfigError`` on an unknown or ill-typed
    key, a missing required field, or a ``ValueError`` from a ``__post_init__``.
    """
    leaves = {leaf.path: leaf for leaf in config_leaves(cls)}
    values: dict[str, Any] = {}
    for path, value in (defaults or {}).items():
        if path not in leaves:
            raise ConfigError(f"unknown preset key {path!r}{suggest(path, leaves)}")
        values[path] = coerce(leaves[path], value, "preset ")
    if file is not None:
        values.update(read_file(cls, leaves, Path(file)))
    if args is not None:
        values.update({path: getattr(args, path) for path in leaves if hasattr(args, path)})
    return typing.cast(T, build(cls, values, "", None))


def parse_setting(cls: type, path: str, text: str) -> Any:
    """The value ``text`` gives field ``path`` of ``cls`` (``phase1.max_patterns``), parsed as its flag would be.
    Raises ``ConfigError`` on an unknown path (naming the closest one) or a value of the wrong kind."""
    leaves = {leaf.path: leaf for leaf in config_leaves(cls)}
    if path not in leaves:
        raise ConfigError(f"unknown key {path!r}{suggest(path, leaves)}")
    try:
        return flag_type(leaves[path])(text)
    except argparse.ArgumentTypeError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def replace_setting(config: T, path: str, value: Any) -> T:
    """``config`` with field ``path`` (dotted through nested dataclasses) set to ``value``; the dataclasses'
    ``__post_init__`` checks run, and their ``ValueError`` comes out as a ``ConfigError`` naming ``path``."""
    names = path.split(".")
    chain: list[Any] = [config]
    for name in names[:-1]:
        chain.append(getattr(chain[-1], name))
    try:
        for parent, name in zip(reversed(chain), reversed(names), strict=True):
            value = dataclasses.replace(parent, **{name: value})
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    return typing.cast(T, value)


def dump_config(config: Any, exclude: Collection[str] = ()) -> str:
    """``config`` as TOML, nested dataclasses as tables, without the field paths in ``exclude``;
    ``load_config(type(config), file=...)`` gives it back.

    A None is left out where the default is None too, and written ``"none"`` otherwise (TOML has no null).
    """
    return tomli_w.dumps(toml_table(config, config_leaves(type(config)), "", exclude))
