"""``ennc-ql bench phase1``: the learner's phase 1 against the size of its store::

out = bench_phase1((100_000, 300_000))
out["rows"][0]["seconds"], out["rows"][0]["prototypes_per_action"]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from algorithm.phase1 import phase1
from learner.config import LearnerConfig
from sim import N_ACTIONS
from tools.bench.exploration import cmommt_experience
from tools.progress import ProgressBar


def bench_phase1(store_sizes: tuple[int, ...] = (100_000, 300_000, 1_000_000), seed: int = 0) -> dict[str, Any]:
    """Phase 1 as the learner runs it (its default ``Phase1Config``) on stores of each size of random-exploration
    tuples: seconds of the fit and prototypes per action. The learner fits ENNC on at most ``max_patterns`` tuples
    per action but computes the Q targets on all of them, so the time grows with the store more slowly than it."""
    config = LearnerConfig().phase1
    rows = []
    with ProgressBar("bench phase1", total=len(store_sizes) + 1, unit="steps") as bar:
        bar.show(status=f"exploring for {max(store_sizes):,} tuples")
        data = cmommt_experience(max(store_sizes), seed)
        bar.mark(f"{len(data):,} tuples", n=1)
        for size in store_sizes:
            bar.show(status=f"phase 1 on {size:,} tuples")
            # The newest tuples of a store of this size (the store keeps the newest).
            store = data.take(np.arange(len(data) - size, len(data)))
            start = time.perf_counter()
            result = phase1(store, N_ACTIONS, config, seed=seed)
            seconds = time.perf_counter() - start
            sizes = [int(s) for s in result.discretization.sizes()]
            rows.append({"store_tuples": size, "seconds": round(seconds, 2), "prototypes_per_action": sizes})
            bar.mark(f"{size:,} tuples: {seconds:.1f} s", n=bar.n + 1)
    return {"max_patterns": config.max_patterns, "max_iterations": config.max_iterations, "rows": rows}


def phase1_table(out: dict[str, Any]) -> str:
    head = (
        f"phase 1 as the learner runs it (at most {out['max_patterns']:,} tuples per action fitted, "
        f"{out['max_iterations']} iteration)"
    )
    lines = [
        f"  {r['store_tuples']:>9,} tuples: {r['seconds']:7.2f} s, "
        f"{sum(r['prototypes_per_action']) / len(r['prototypes_per_action']):.0f} prototypes per action"
        for r in out["rows"]
    ]
    return "\n".join([head, *lines])
