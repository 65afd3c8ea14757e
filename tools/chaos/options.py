"""The options of a chaos run: the faults by name, the defaults, and the parsers of a duration and a list of faults
(``ennc-ql chaos``'s ``--duration``, ``--soak`` and ``--faults`` become :class:`ChaosOptions`)."""

from __future__ import annotations

import re
from dataclasses import dataclass

FAULTS = (
    "learner-kill",
    "router-restart",
    "actor-stop",
    "actor-kill",
    "partition",
    "delay",
    "loss",
    "poison",
    "spoof",
    "unauthenticated",
    "wrong-certificate",
    "oversize",
)
"""Every fault, in the order of the rotation (the table of the package's docstring)."""
SECURE_ONLY = frozenset({"unauthenticated", "wrong-certificate"})
"""Faults that test TLS and authentication, which a plain run does not have."""
NETWORK_FAULTS = frozenset({"partition", "delay", "loss"})
"""Faults between hosts: with any of them in the rotation every process runs in a network namespace of its own."""

DEFAULT_DURATION_S, DEFAULT_FAULT_INTERVAL_S = 120.0, 20.0
DEFAULT_RSS_INTERVAL_S, SOAK_RSS_INTERVAL_S = 10.0, 60.0


@dataclass(frozen=True, slots=True)
class ChaosOptions:
    duration: float
    """Seconds from the start of the cluster to the drain."""
    secure: bool
    fault_interval: float
    faults: tuple[str, ...]
    rss_interval: float


def parse_duration(text: str) -> float:
    """Seconds of ``90``, ``90s``, ``30m`` or ``2h``.

    >>> parse_duration("30m"), parse_duration("90s"), parse_duration("2h"), parse_duration("45")
    (1800.0, 90.0, 7200.0, 45.0)
    """
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([smh]?)\s*", text)
    if match is None or float(match[1]) <= 0:
        raise ValueError(f"{text!r} is not a duration such as 90s, 30m or 2h")
    return float(match[1]) * {"": 1, "s": 1, "m": 60, "h": 3600}[match[2]]


def parse_faults(text: str | None, secure: bool) -> tuple[str, ...]:
    """The faults named in ``text`` (comma-separated, in that order), or every one that applies."""
    if text is None:
        return tuple(f for f in FAULTS if secure or f not in SECURE_ONLY)
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    for name in names:
        if name not in FAULTS:
            raise ValueError(f"unknown fault {name!r} (valid: {', '.join(FAULTS)})")
        if name in SECURE_ONLY and not secure:
            raise ValueError(f"{name} tests TLS and authentication: it needs --secure")
    if not names:
        raise ValueError("no fault named")
    return names
