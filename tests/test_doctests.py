"""The usage examples in the library's docstrings run (the modules whose docstrings carry ``>>>`` examples)."""

from __future__ import annotations

import doctest
import importlib

import pytest


@pytest.mark.parametrize(
    "module",
    [
        "algorithm.qtable",
        "algorithm.checks",
        "algorithm.policy_file",
        "actors.config",
        "protocol.zenoh_transport",
        "tools.chaos.options",
        "tools.config",
    ],
)
def test_documentation_examples_run(module: str) -> None:
    result = doctest.testmod(importlib.import_module(module))
    assert result.attempted > 0 and result.failed == 0
