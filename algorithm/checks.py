"""Checks of configuration values, shared by every process's configuration dataclass (``__post_init__``): each
raises ``ValueError`` with a message that starts with the field's name, which the CLI prints as a one-line error.

>>> require_at_least(1, arenas=0)
Traceback (most recent call last):
ValueError: arenas must be at least 1, got 0
"""

from __future__ import annotations

from collections.abc import Iterable

from protocol import check_id


def require_id(name: str, value: str) -> None:
    """A key-expression chunk (letters, digits, '_', '.', '-')."""
    try:
        check_id(value, name)
    except ValueError as exc:
        raise ValueError(str(exc)) from None


def require_known(name: str, value: str, known: Iterable[str]) -> None:
    known = list(known)
    if value not in known:
        raise ValueError(f"{name}: unknown {value!r} (known: {', '.join(sorted(known))})")


def require_at_least(lo: int, **values: int) -> None:
    for name, value in values.items():
        if value < lo:
            raise ValueError(f"{name} must be at least {lo}, got {value}")


def require_at_most(hi: int, **values: int) -> None:
    for name, value in values.items():
        if value > hi:
            raise ValueError(f"{name} must be at most {hi}, got {value}")


def require_positive(**values: float | None) -> None:
    """Every value > 0 (None, where a field allows it, is not checked)."""
    for name, value in values.items():
        if value is not None and not value > 0:
            raise ValueError(f"{name} must be positive, got {value}")
