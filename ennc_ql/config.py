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
import ast
import dataclasses
import difflib
import inspect
import itertools
import textwrap
import tomllib
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any, Literal, Protocol, TypeVar

import tomli_w

T = TypeVar("T")
N = TypeVar("N", int, float)


class ConfigError(ValueError):
    """A configuration that cannot be built; the message is one line, fit to print after the command's name."""


class _AddsArguments(Protocol):  # an ArgumentParser or an argument group
    def add_argument(self, *args: Any, **kwargs: Any) -> Any: ...


class _Mismatch(Exception):
    """A value not of the expected kind; carries what was expected, e.g. 'an integer'."""


@dataclasses.dataclass(frozen=True)
class _Leaf:
    """One non-dataclass field, reached from the top class by ``path`` (``phase1.max_patterns``)."""

    path: str
    kind: Any  # the annotation without its ``| None``
    optional: bool
    doc: str
    default: Any  # effective default (from the enclosing default instance); dataclasses.MISSING if required
    metadata: Mapping[str, Any]


def positive(kind: type[N]) -> Callable[[str], N]:
    """The argparse ``type`` of a positive number: ``positive(int)`` or ``positive(float)``.

    >>> positive(int)("3"), positive(float)("0.5")
    (3, 0.5)
    """
    noun = "integer" if kind is int else "number"

    def parse(text: str) -> N:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {noun}, got {text!r}") from None
        if not value > 0:  # also rejects nan
            raise argparse.ArgumentTypeError(f"expected a positive {noun}, got {text!r}")
        return value

    parse.__name__ = f"positive_{kind.__name__}"
    return parse


def field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings of a class and its bases: the string literal right after each annotated field.

    Classes whose source cannot be read (defined interactively) contribute none.
    """
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object:
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        except (OSError, TypeError):
            continue
        body = next(node for node in tree.body if isinstance(node, ast.ClassDef)).body
        for stmt, after in itertools.pairwise(body):
            if (
                isinstance(stmt, ast.AnnAssign)
                and isinstance(stmt.target, ast.Name)
                and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant)
                and isinstance(after.value.value, str)
            ):
                docs[stmt.target.id] = " ".join(inspect.cleandoc(after.value.value).split())
    return docs


def add_config_flags(
    parser: _AddsArguments,
    cls: type,
    *,
    exclude: Iterable[str] = (),
    defaults: Mapping[str, Any] | None = None,
) -> None:
    """One flag per field of ``cls``: ``store_capacity`` -> ``--store-capacity``, ``phase1.n_cycles`` ->
    ``--phase1-n-cycles``; bools get ``--x/--no-x``. ``exclude`` names field paths (a nested field's path drops all
    of it); ``defaults`` are the command's presets by field path, shown as the default in the help.

    A flag sets its attribute, named by the field path (``getattr(args, "phase1.n_cycles")``), only when given, so
    ``load_config`` can rank it above the file.
    """
    leaves, excluded = _leaves(cls), tuple(exclude)
    _check_paths(cls, leaves, excluded, "exclude", tables=True)
    _check_paths(cls, leaves, defaults or {}, "defaults", tables=False)
    for leaf in leaves:
        if any(leaf.path == e or leaf.path.startswith(e + ".") for e in excluded):
            continue
        default = (defaults or {}).get(leaf.path, leaf.default)
        shown = "required" if default is dataclasses.MISSING else f"default: {_show(leaf, default)}"
        help_text = f"{leaf.doc} ({shown})" if leaf.doc else f"({shown})"
        flag = "--" + leaf.path.replace(".", "-").replace("_", "-")
        common = {"dest": leaf.path, "default": argparse.SUPPRESS, "help": help_text.replace("%", "%%")}
        if leaf.kind is bool and not leaf.optional and "parse" not in leaf.metadata:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, **common)
        else:
            parser.add_argument(flag, type=_flag_type(leaf), metavar=_metavar(leaf), **common)


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
    leaves = {leaf.path: leaf for leaf in _leaves(cls)}
    values: dict[str, Any] = {}
    for path, value in (defaults or {}).items():
        if path not in leaves:
            raise ConfigError(f"unknown preset key {path!r}{_suggest(path, leaves)}")
        values[path] = _coerce(leaves[path], value, "preset ")
    if file is not None:
        values.update(_read_file(cls, leaves, Path(file)))
    if args is not None:
        values.update({path: getattr(args, path) for path in leaves if hasattr(args, path)})
    return typing.cast(T, _build(cls, values, "", None))


def parse_setting(cls: type, path: str, text: str) -> Any:
    """The value ``text`` gives field ``path`` of ``cls`` (``phase1.max_patterns``), parsed as its flag would be.
    Raises ``ConfigError`` on an unknown path (naming the closest one) or a value of the wrong kind."""
    leaves = {leaf.path: leaf for leaf in _leaves(cls)}
    if path not in leaves:
        raise ConfigError(f"unknown key {path!r}{_suggest(path, leaves)}")
    try:
        return _flag_type(leaves[path])(text)
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


def dump_config(config: Any) -> str:
    """``config`` as TOML, nested dataclasses as tables; ``load_config(type(config), file=...)`` gives it back.

    A None is left out where the default is None too, and written ``"none"`` otherwise (TOML has no null).
    """
    return tomli_w.dumps(_table(config, _leaves(type(config)), ""))


def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except NameError as exc:
        raise TypeError(f"cannot resolve the annotations of {cls.__qualname__}: {exc}") from None


def _split_optional(annotation: Any) -> tuple[Any, bool]:
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0], len(args) < len(typing.get_args(annotation))
    return annotation, False


def _default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _nested(cls: type) -> dict[str, type]:
    """The init fields of ``cls`` whose type is a dataclass, by name."""
    hints = _hints(cls)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(cls)
        if f.init and isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name])
    }


def _leaves(cls: type, prefix: str = "", base: Any = None) -> list[_Leaf]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints, docs, nested = _hints(cls), field_docs(cls), _nested(cls)
    leaves: list[_Leaf] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        default = _default(f) if base is None else getattr(base, f.name)
        if f.name in nested:
            inner = None if default is dataclasses.MISSING else default
            leaves.extend(_leaves(nested[f.name], f"{prefix}{f.name}.", inner))
            continue
        kind, optional = _split_optional(hints[f.name])
        leaf = _Leaf(prefix + f.name, kind, optional, docs.get(f.name, ""), default, f.metadata)
        if "parse" not in f.metadata:
            _describe(kind)  # raises TypeError for a type without a parse hook
        leaves.append(leaf)
    return leaves


def _check_paths(cls: type, leaves: list[_Leaf], paths: Iterable[str], what: str, *, tables: bool) -> None:
    known = {leaf.path for leaf in leaves}
    if tables:  # a nested dataclass's own path, and its parents'
        known |= {leaf.path.rsplit(".", n)[0] for leaf in leaves for n in range(1, leaf.path.count(".") + 1)}
    for path in paths:
        if path not in known:
            raise ValueError(f"{what}: {cls.__qualname__} has no field {path!r}{_suggest(path, known)}")


def _suggest(key: str, known: Iterable[str], prefix: str = "") -> str:
    close = difflib.get_close_matches(key, list(known), n=1)
    return f" (did you mean {prefix + close[0]!r}?)" if close else ""


def _describe(kind: Any) -> str:
    """What a value of ``kind`` looks like, for messages; TypeError for an unsupported type."""
    names = {int: "an integer", float: "a number", str: "a string", bool: "true or false", Path: "a path"}
    if kind in names:
        return names[kind]
    if typing.get_origin(kind) is Literal:
        return "one of " + ", ".join(repr(c) for c in typing.get_args(kind))
    if typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        if len(items) == 2 and items[1] is Ellipsis:
            return f"an array, each {_describe(items[0])}"
        return f"an array of {len(items)}: " + ", ".join(_describe(item) for item in items)
    raise TypeError(f"unsupported config field type {kind!r}; give it field(metadata={{'parse': fn}})")


def _convert(kind: Any, value: Any) -> Any:
    """A TOML (or Python) value as ``kind``; _Mismatch if it is not one."""
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        value = float(value) if ok else value
    elif kind is str:
        ok = isinstance(value, str)
    elif kind is Path:
        ok = isinstance(value, str | Path)
        value = Path(value) if ok else value
    elif typing.get_origin(kind) is Literal:
        ok = any(value == c and type(value) is type(c) for c in typing.get_args(kind))
    elif typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        ok = isinstance(value, list | tuple)
        if ok and len(items) == 2 and items[1] is Ellipsis:
            items = (items[0],) * len(value)
        try:
            if not ok or len(items) != len(value):
                raise _Mismatch
            return tuple(_convert(item, v) for item, v in zip(items, value, strict=True))
        except _Mismatch:
            raise _Mismatch(_describe(kind)) from None
    else:
        ok = isinstance(kind, type) and isinstance(value, kind)
    if not ok:
        raise _Mismatch(_describe(kind))
    return value


def _is_none(leaf: _Leaf, value: Any) -> bool:
    return leaf.optional and (value is None or (isinstance(value, str) and value.lower() == "none"))


def _coerce(leaf: _Leaf, value: Any, where: str) -> Any:
    if _is_none(leaf, value):
        return None
    try:
        if "parse" in leaf.metadata and isinstance(value, str):
            return leaf.metadata["parse"](value)
        return _convert(leaf.kind, value)
    except (ValueError, _Mismatch) as exc:
        expected = f"must be {exc}" if isinstance(exc, _Mismatch) else f"is invalid ({exc})"
        expected += " or none" if leaf.optional and isinstance(exc, _Mismatch) else ""
        raise ConfigError(f"{where}key {leaf.path!r} {expected}, got {value!r}") from None
    except TypeError:  # a parse hook's type without a string: say what the hook reads
        raise ConfigError(f"{where}key {leaf.path!r} must be a string, got {value!r}") from None


def _read_file(cls: type, leaves: Mapping[str, _Leaf], file: Path) -> dict[str, Any]:
    try:
        with file.open("rb") as fh:
            data = tomllib.load(fh)
    except OSError as exc:
        raise ConfigError(f"cannot read config file {str(file)!r}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{file}: {exc}") from None
    values: dict[str, Any] = {}

    def walk(klass: type, table: Mapping[str, Any], prefix: str) -> None:
        names, nested = [f.name for f in dataclasses.fields(klass) if f.init], _nested(klass)
        for key, value in table.items():
            path = prefix + key
            if key not in names:
                raise ConfigError(f"{file}: unknown key {path!r}{_suggest(key, names, prefix)}")
            if key in nested:
                if not isinstance(value, dict):
                    raise ConfigError(f"{file}: key {path!r} must be a table ([{path}]), got {value!r}")
                walk(nested[key], value, path + ".")
            else:
                values[path] = _coerce(leaves[path], value, f"{file}: ")

    walk(cls, data, "")
    return values


def _build(cls: type, values: Mapping[str, Any], prefix: str, base: Any) -> Any:
    """``cls`` from ``values`` by path; fields not given come from ``base`` (or the dataclass defaults)."""
    nested, kwargs = _nested(cls), {}
    for f in dataclasses.fields(cls):
        path = prefix + f.name
        if not f.init:
            continue
        default = _default(f) if base is None else getattr(base, f.name)
        if f.name in nested:
            if any(key.startswith(path + ".") for key in values) or default is dataclasses.MISSING:
                inner = None if default is dataclasses.MISSING else default
                kwargs[f.name] = _build(nested[f.name], values, path + ".", inner)
        elif path in values:
            kwargs[f.name] = values[path]
        elif default is dataclasses.MISSING:
            raise ConfigError(f"missing required key {path!r} (give --{path.replace('.', '-').replace('_', '-')})")
    try:
        return cls(**kwargs) if base is None else dataclasses.replace(base, **kwargs)
    except ConfigError:
        raise
    except ValueError as exc:
        where = f"{prefix[:-1]}: " if prefix else ""
        raise ConfigError(where + " ".join(str(exc).split())) from None


def _flag_type(leaf: _Leaf) -> Callable[[str], Any]:
    parse_hook = leaf.metadata.get("parse")

    def parse_item(kind: Any, text: str) -> Any:
        if kind is str:
            return text
        if kind is bool:
            if text.lower() not in ("true", "false"):
                raise argparse.ArgumentTypeError(f"expected true or false, got {text!r}")
            return text.lower() == "true"
        if typing.get_origin(kind) is Literal:
            for choice in typing.get_args(kind):
                if str(choice) == text:
                    return choice
            choices = ", ".join(str(c) for c in typing.get_args(kind))
            raise argparse.ArgumentTypeError(f"invalid choice: {text!r} (choose from {choices})")
        if typing.get_origin(kind) is tuple:
            items = typing.get_args(kind)
            parts = [p.strip() for p in text.split(",")] if text.strip() else []
            if len(items) == 2 and items[1] is Ellipsis:
                items = (items[0],) * len(parts)
            if len(items) != len(parts):
                raise argparse.ArgumentTypeError(f"expected {len(items)} comma-separated values, got {text!r}")
            return tuple(parse_item(item, part) for item, part in zip(items, parts, strict=True))
        try:
            return kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {_describe(kind)}, got {text!r}") from None

    def parse(text: str) -> Any:
        if leaf.optional and text.lower() == "none":
            return None
        if parse_hook is None:
            return parse_item(leaf.kind, text)
        try:
            return parse_hook(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc) or f"invalid value {text!r}") from None

    parse.__name__ = leaf.path  # argparse names the type in some of its own messages
    return parse


def _metavar(leaf: _Leaf) -> str:
    if "metavar" in leaf.metadata:
        base = str(leaf.metadata["metavar"])
    elif "parse" in leaf.metadata:
        base = "VALUE"
    else:
        base = _metavar_of(leaf.kind)
    return f"{base}|none" if leaf.optional else base


def _metavar_of(kind: Any) -> str:
    if typing.get_origin(kind) is Literal:
        return "{" + ",".join(str(c) for c in typing.get_args(kind)) + "}"
    if typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        if len(items) == 2 and items[1] is Ellipsis:
            return f"{_metavar_of(items[0])},..."
        return ",".join(_metavar_of(item) for item in items)
    return {int: "INT", float: "FLOAT", str: "TEXT", bool: "BOOL", Path: "PATH"}.get(kind, "VALUE")


def _show(leaf: _Leaf, value: Any) -> str:
    """A default as one would type it on the command line."""
    if value is None:
        return "none"
    if "format" in leaf.metadata:
        return str(leaf.metadata["format"](value))
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value) if value else "''"
    if isinstance(value, str) and not value:
        return "''"
    return str(value)


def _to_toml(leaf: _Leaf, value: Any) -> Any:
    if isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple | list):
        return [str(v) if isinstance(v, Path) else v for v in value]
    return leaf.metadata.get("format", str)(value)


def _table(config: Any, leaves: list[_Leaf], prefix: str) -> dict[str, Any]:
    by_path = {leaf.path: leaf for leaf in leaves}
    nested, table = _nested(type(config)), dict[str, Any]()
    for f in dataclasses.fields(config):
        if not f.init:
            continue
        value, path = getattr(config, f.name), prefix + f.name
        if f.name in nested:
            inner = _table(value, leaves, path + ".")
            if inner:
                table[f.name] = inner
        elif value is None:
            if by_path[path].default is not None:
                table[f.name] = "none"
        else:
            table[f.name] = _to_toml(by_path[path], value)
    return table
