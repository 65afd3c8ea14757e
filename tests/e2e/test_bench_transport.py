"""``ennc-ql bench transport`` on a short run: counts, not timings (tests never assert wall-clock figures)."""

from __future__ import annotations

import pytest

from tools.bench.transport import bench_transport

pytestmark = pytest.mark.slow


def test_every_published_tuple_is_stored_once_and_rates_are_reported() -> None:
    batch_size = 1024
    out = bench_transport(actors=2, batch_size=batch_size, seconds=1.0)

    assert out["batches_sent"] > 0
    assert out["lost"] == 0 and out["gaps"] == 0 and out["duplicates"] == 0
    # Every batch the publishers sent went through the learner's receive path into its store, exactly once.
    assert out["tuples_stored"] == out["batches_sent"] * batch_size
    assert out["raw_batches_received"] == out["raw_batches_sent"] > 0
    assert out["tuples_per_s"] > 0 and out["raw_zenoh_tuples_per_s"] > 0
    assert out["ratio"] == pytest.approx(out["tuples_per_s"] / out["raw_zenoh_tuples_per_s"], abs=1e-3)
    assert {"actors", "batch_size", "tuples_per_s", "raw_zenoh_tuples_per_s", "ratio", "lost"} <= out.keys()
