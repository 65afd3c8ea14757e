"""``ennc-ql bench broadcast`` and ``bench phase1``, the scaling table's commands (figures only, no timing asserted)."""

from __future__ import annotations

import json

import pytest

from ennc_ql.cli import main
from protocol import N_ACTIONS
from sim import scenario

DIM = 6


def test_bench_broadcast_measures_each_size_and_its_bytes_grow_as_the_message_layout_says(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["bench", "broadcast", "--prototypes", "10", "60", "--rounds", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    robots = scenario().n_robots
    assert (out["robots"], out["actions"], out["rounds"]) == (robots, N_ACTIONS, 2)
    small, large = out["rows"]
    assert (small["prototypes_per_action"], large["prototypes_per_action"]) == (10, 60)
    # Per prototype: its d float32 coordinates and float32 label, and a float32 Q value and uint32 visit count per
    # robot (docs/reference/protocol.md, PolicyUpdate); msgpack's bin headers may grow by a few bytes between the sizes.
    per_prototype = DIM * 4 + 4 + robots * (4 + 4)
    assert abs(large["bytes"] - small["bytes"] - 50 * N_ACTIONS * per_prototype) <= 4 * 6
    for row in out["rows"]:
        assert all(row[k] > 0 for k in ("build_ms", "encode_ms", "decode_ms", "apply_ms", "delivery_ms"))


def test_bench_broadcast_prints_a_table_without_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "broadcast", "--prototypes", "5", "--rounds", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"policy broadcast, {scenario().n_robots} robots x {N_ACTIONS} actions")
    assert lines[2].split()[0] == "5" and len(lines) == 3


def test_bench_phase1_fits_each_store_size_on_its_newest_tuples(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "phase1", "--store-sizes", "3000", "6000", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["store_tuples"] for r in out["rows"]] == [3000, 6000]
    for row in out["rows"]:
        assert len(row["prototypes_per_action"]) == N_ACTIONS and min(row["prototypes_per_action"]) >= 1
        assert row["seconds"] > 0
