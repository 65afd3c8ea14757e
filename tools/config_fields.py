"""The machinery of ``tools.config``: a config dataclass as a list of leaf fields (``phase1.max_patterns``),
and how one leaf's value is read from TOML, parsed from a flag, checked, shown in the help and written back.

Over 400 lines: every step of a leaf's life (read, parse, check, document, write) follows the same type analysis, and
split apart each part would repeat it."""

import argparse
import ast
import dataclasses
import difflib
import functools
import inspect
import itertools
import math
import re
import textwrap
import tomllib
import types
import typing
from collections.abc import Callable, Collection, Iterable, Mapping
from pathlib import Path
from typing import Any, Literal

_ROLE = re.compile(r":[a-z]+:`~?([^`]+)`")  # :mod:`x`, :class:`~x.Y`


def plain(text: str) -> str:
    """``text`` without reStructuredText markup, for the terminal: ``:mod:`x``` and ````x```` become ``x``.

    >>> plain("see :mod:`protocol.security` and ``ennc-ql up``")
    'see protocol.security and ennc-ql up'
    """
    return _ROLE.sub(r"\1", text).replace("``", "")


class ConfigError(ValueError):
    """A configuration that cannot be built; the message is one line, fit to print after the command's name."""


class UnknownKey(ConfigError):
    """A file's key that its configuration has no field for: ``path`` (``phase2.alpha``), for a hint naming the
    configuration that has it."""

    def __init__(self, message: str, path: str) -> None:
        super().__init__(message)
        self.path = path


class Mismatch(Exception):
    """A value not of the expected kind; carries what was expected, e.g. 'an integer'."""


@dataclasses.dataclass(frozen=True)
class Leaf:
    """One non-dataclass field, reached from the top class by ``path`` (``phase1.max_patterns``)."""

    path: str
    kind: Any  # the annotation without its ``| None``
    optional: bool
    doc: str
    default: Any  # effective default (from the enclosing default instance); dataclasses.MISSING if required
    metadata: Mapping[str, Any]


def field_docs(cls: type) -> dict[str, str]:
    """Attribute docstrings of a class and its bases: the string literal right after each annotated field.

    Classes whose source cannot be read (defined interactively) contribute none.
    """
    return dict(_field_docs(cls))


@functools.cache
def _field_docs(cls: type) -> dict[str, str]:
    # Cached: building a command's parser asks for the same classes again and again, and each answer re-reads and
    # re-parses their source (about 0.07 s of every ennc-ql command's start).
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
                docs[stmt.target.id] = plain(" ".join(inspect.cleandoc(after.value.value).split()))
    return docs


def resolve_hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except NameError as exc:
        raise TypeError(f"cannot resolve the annotations of {cls.__qualname__}: {exc}") from None


def split_optional(annotation: Any) -> tuple[Any, bool]:
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0], len(args) < len(typing.get_args(annotation))
    return annotation, False


def field_default(f: dataclasses.Field[Any]) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def nested_fields(cls: type) -> dict[str, type]:
    """The init fields of ``cls`` whose type is a dataclass, by name."""
    hints = resolve_hints(cls)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(cls)
        if f.init and isinstance(hints[f.name], type) and dataclasses.is_dataclass(hints[f.name])
    }


def config_leaves(cls: type, prefix: str = "", base: Any = None) -> list[Leaf]:
    if not dataclasses.is_dataclass(cls):
        raise TypeError(f"{cls!r} is not a dataclass")
    hints, docs, nested = resolve_hints(cls), field_docs(cls), nested_fields(cls)
    leaves: list[Leaf] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        default = field_default(f) if base is None else getattr(base, f.name)
        if f.name in nested:
            inner = None if default is dataclasses.MISSING else default
            leaves.extend(config_leaves(nested[f.name], f"{prefix}{f.name}.", inner))
            continue
        kind, optional = split_optional(hints[f.name])
        leaf = Leaf(prefix + f.name, kind, optional, docs.get(f.name, ""), default, f.metadata)
        if "parse" not in f.metadata:
            describe(kind)  # raises TypeError for a type without a parse hook
        leaves.append(leaf)
    return leaves


def check_paths(cls: type, leaves: list[Leaf], paths: Iterable[str], what: str, *, tables: bool) -> None:
    known = {leaf.path for leaf in leaves}
    if tables:  # a nested dataclass's own path, and its parents'
        known |= {leaf.path.rsplit(".", n)[0] for leaf in leaves for n in range(1, leaf.path.count(".") + 1)}
    for path in paths:
        if path not in known:
            raise ValueError(f"{what}: {cls.__qualname__} has no field {path!r}{suggest(path, known)}")


def suggest(key: str, known: Iterable[str], prefix: str = "") -> str:
    close = difflib.get_close_matches(key, list(known), n=1)
    return f" (did you mean {prefix + close[0]!r}?)" if close else ""


def describe(kind: Any) -> str:
    """What a value of ``kind`` looks like, for messages; TypeError for an unsupported type."""
    names = {int: "an integer", float: "a finite number", str: "a string", bool: "true or false", Path: "a path"}
    if kind in names:
        return names[kind]
    if typing.get_origin(kind) is Literal:
        return "one of " + ", ".join(repr(c) for c in typing.get_args(kind))
    if typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        if len(items) == 2 and items[1] is Ellipsis:
            return f"an array, each {describe(items[0])}"
        return f"an array of {len(items)}: " + ", ".join(describe(item) for item in items)
    raise TypeError(f"unsupported config field type {kind!r}; give it field(metadata={{'parse': fn}})")


def convert(kind: Any, value: Any) -> Any:
    """A TOML (or Python) value as ``kind``; Mismatch if it is not one."""
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        # inf and nan parse as numbers, and a duration of inf would train for ever
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
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
                raise Mismatch
            return tuple(convert(item, v) for item, v in zip(items, value, strict=True))
        except Mismatch:
            raise Mismatch(describe(kind)) from None
    else:
        ok = isinstance(kind, type) and isinstance(value, kind)
    if not ok:
        raise Mismatch(describe(kind))
    return value


def is_none(leaf: Leaf, value: Any) -> bool:
    return leaf.optional and (value is None or (isinstance(value, str) and value.lower() == "none"))


def coerce(leaf: Leaf, value: Any, where: str) -> Any:
    if is_none(leaf, value):
        return None
    try:
        if "parse" in leaf.metadata and isinstance(value, str):
            return leaf.metadata["parse"](value)
        return convert(leaf.kind, value)
    except (ValueError, Mismatch) as exc:
        expected = f"must be {exc}" if isinstance(exc, Mismatch) else f"is invalid ({exc})"
        expected += " or none" if leaf.optional and isinstance(exc, Mismatch) else ""
        raise ConfigError(f"{where}key {leaf.path!r} {expected}, got {value!r}") from None
    except TypeError:  # a parse hook's type without a string: say what the hook reads
        raise ConfigError(f"{where}key {leaf.path!r} must be a string, got {value!r}") from None


def read_file(cls: type, leaves: Mapping[str, Leaf], file: Path) -> dict[str, Any]:
    try:
        raw = file.read_bytes()
    except OSError as exc:
        raise ConfigError(f"cannot read config file {str(file)!r}: {exc.strerror}") from None
    if raw.startswith(b"PK\x03\x04"):
        raise ConfigError(f"{file}: an .npz archive (a policy file or a checkpoint), not a TOML configuration file")
    try:
        data = tomllib.loads(raw.decode("utf-8-sig"))  # a byte-order mark, as some Windows editors write, is fine
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{file}: not a TOML configuration file (not UTF-8 text: byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{file}: {exc}") from None
    values: dict[str, Any] = {}

    def walk(klass: type, table: Mapping[str, Any], prefix: str) -> None:
        names, nested = [f.name for f in dataclasses.fields(klass) if f.init], nested_fields(klass)
        for key, value in table.items():
            path = prefix + key
            if key not in names:
                raise UnknownKey(f"{file}: unknown key {path!r}{suggest(key, names, prefix)}", path)
            if key in nested:
                if not isinstance(value, dict):
                    raise ConfigError(f"{file}: key {path!r} must be a table ([{path}]), got {value!r}")
                walk(nested[key], value, path + ".")
            else:
                values[path] = coerce(leaves[path], value, f"{file}: ")

    walk(cls, data, "")
    return values


def build(cls: type, values: Mapping[str, Any], prefix: str, base: Any) -> Any:
    """``cls`` from ``values`` by path; fields not given come from ``base`` (or the dataclass defaults)."""
    nested, kwargs = nested_fields(cls), {}
    for f in dataclasses.fields(cls):
        path = prefix + f.name
        if not f.init:
            continue
        default = field_default(f) if base is None else getattr(base, f.name)
        if f.name in nested:
            if any(key.startswith(path + ".") for key in values) or default is dataclasses.MISSING:
                inner = None if default is dataclasses.MISSING else default
                kwargs[f.name] = build(nested[f.name], values, path + ".", inner)
        elif path in values:
            kwargs[f.name] = values[path]
        elif default is dataclasses.MISSING:
            raise ConfigError(f"missing required key {path!r} (give {flag_name(path)})")
    try:
        return cls(**kwargs) if base is None else dataclasses.replace(base, **kwargs)
    except ConfigError:
        raise
    except ValueError as exc:
        where = f"{prefix[:-1]}: " if prefix else ""
        raise ConfigError(where + " ".join(str(exc).split())) from None


def flag_name(path: str) -> str:
    """The flag of a field path; a field that repeats its table's name says it once.

    >>> flag_name("phase1.n_cycles"), flag_name("learner.learner_id")
    ('--phase1-n-cycles', '--learner-id')
    """
    parts = path.split(".")
    for i in range(1, len(parts)):
        if parts[i].startswith(parts[i - 1] + "_"):
            parts[i] = parts[i].removeprefix(parts[i - 1] + "_")
    return "--" + "-".join(parts).replace("_", "-")


def flag_type(leaf: Leaf, choices: Collection[str] | None = None) -> Callable[[str], Any]:
    """The argparse ``type`` of a leaf's flag; ``choices``: the only values a text field takes."""
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
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {describe(kind)}, got {text!r}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected {describe(kind)}, got {text!r}")
        return value

    def parse(text: str) -> Any:
        if leaf.optional and text.lower() == "none":
            return None
        if choices is not None and text not in choices:
            close = difflib.get_close_matches(text, list(choices), n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise argparse.ArgumentTypeError(f"unknown value {text!r} ({hint}one of {', '.join(choices)})")
        if parse_hook is None:
            return parse_item(leaf.kind, text)
        try:
            return parse_hook(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc) or f"invalid value {text!r}") from None

    parse.__name__ = leaf.path  # argparse names the type in some of its own messages
    return parse


def metavar(leaf: Leaf, choices: Collection[str] | None = None) -> str:
    if choices is not None:
        base = "{" + ",".join(choices) + "}"
    elif "metavar" in leaf.metadata:
        base = str(leaf.metadata["metavar"])
    elif "parse" in leaf.metadata:
        base = "VALUE"
    else:
        base = metavar_of(leaf.kind)
    return f"{base}|none" if leaf.optional else base


def metavar_of(kind: Any) -> str:
    if typing.get_origin(kind) is Literal:
        return "{" + ",".join(str(c) for c in typing.get_args(kind)) + "}"
    if typing.get_origin(kind) is tuple:
        items = typing.get_args(kind)
        if len(items) == 2 and items[1] is Ellipsis:
            return f"{metavar_of(items[0])},..."
        return ",".join(metavar_of(item) for item in items)
    return {int: "INT", float: "FLOAT", str: "TEXT", bool: "BOOL", Path: "PATH"}.get(kind, "VALUE")


def show(leaf: Leaf, value: Any) -> str:
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


def to_toml(leaf: Leaf, value: Any) -> Any:
    if isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, tuple | list):
        return [str(v) if isinstance(v, Path) else v for v in value]
    return leaf.metadata.get("format", str)(value)


def toml_table(config: Any, leaves: list[Leaf], prefix: str, exclude: Collection[str] = ()) -> dict[str, Any]:
    by_path = {leaf.path: leaf for leaf in leaves}
    nested, table = nested_fields(type(config)), dict[str, Any]()
    for f in dataclasses.fields(config):
        value, path = getattr(config, f.name), prefix + f.name
        if not f.init or path in exclude:
            continue
        if f.name in nested:
            inner = toml_table(value, leaves, path + ".", exclude)
            if inner:
                table[f.name] = inner
        elif value is None:
            if by_path[path].default is not None:
                table[f.name] = "none"
        else:
            table[f.name] = to_toml(by_path[path], value)
    return table
