"""Tests that need a system package (iptables and iproute2, SLURM, Xvfb, podman) skip with the reason where it is
absent, so ``make test`` is green on a fresh machine with only what the README installs; CI (``.ci/run``) installs
the packages and sets ``ENNC_QL_REQUIRE_<WHAT>=1``, and there a missing package is a failure instead. Usage::

    reason = why_not()                 # None where the package works here
    require("NETNS", reason)           # skip saying why, or fail under ENNC_QL_REQUIRE_NETNS=1
"""

from __future__ import annotations

import os

import pytest

NETNS = "NETNS"
"""Network namespaces with iproute2 and iptables, as root (chaos's network faults, the multi-host test)."""
SLURM = "SLURM"
"""SLURM's and munge's daemons and clients, as root (the SLURM tests start a SLURM of three emulated nodes)."""
_NAMES = {NETNS: "network namespace", SLURM: "SLURM"}


def variable(what: str) -> str:
    """The environment variable that turns ``what``'s skips into failures."""
    return f"ENNC_QL_REQUIRE_{what}"


def required(what: str) -> bool:
    return os.environ.get(variable(what)) == "1"


def require(what: str, reason: str | None) -> None:
    """Nothing if ``reason`` is None; else skip saying ``reason``, or fail where ``ENNC_QL_REQUIRE_<what>=1``."""
    if reason is None:
        return
    if required(what):
        pytest.fail(f"{reason}, but {variable(what)}=1 requires the {_NAMES.get(what, what)} tests to run")
    pytest.skip(reason)
