"""Fixtures and hooks of the whole suite.

``make test`` runs the suite on two pytest-xdist workers. Its end-to-end tests (marked ``slow``) take tens of seconds
each, the others milliseconds to seconds, so the slow ones are collected first: xdist hands out the first quarter of
the collection round-robin, which spreads them over both workers from the start, and the short tests fill the gaps
(longest first; with the slow tests last, one worker would end alone on the last of them).
"""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)  # stable: file order within each part
