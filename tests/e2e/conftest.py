"""Fixtures of the end-to-end tests."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.e2e.cluster import Cluster


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    """A :class:`~tests.e2e.cluster.Cluster` whose processes are all killed at teardown."""
    c = Cluster(tmp_path)
    try:
        yield c
    finally:
        c.kill_all()
