"""``ennc-ql bench ennc``: ENNC against scikit-learn's k-means on the patterns phase 1 trains one classifier on and on
region-shaped patterns that grow thousands of prototypes, and ENNC-QL phase 1 on many tuples::

    out = bench_ennc(patterns=100_000, cycles=250, phase1_tuples=1_000_000)
    out["ratio"], out["regions"]["ratio"], out["phase1_seconds"]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch
from sklearn.cluster import KMeans
from threadpoolctl import threadpool_limits

from algorithm.ennc import ENNC
from algorithm.phase1 import Phase1Config, phase1, standard_scale, to_classes
from sim import N_ACTIONS
from tools.bench.exploration import cmommt_experience
from tools.progress import ProgressBar

REGION_SITES = 64
"""Voronoi sites of the region-shaped classes of :func:`region_patterns`."""
MASK_VALUE = 3.0
"""Value of the masked block in :func:`region_patterns`: like a masked CMOMMT feature after scaling, a constant far
outside the unit cube the unmasked values fill."""


def region_patterns(patterns: int, seed: int = 0, masked_share: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """6-D patterns in the unit cube whose class (0 or 1) is that of the Voronoi region of dims 0–1 they fall in.

    Shaped like CMOMMT states (6-D, a block of features masked to one constant: dims 4–5 for ``masked_share`` of
    the patterns), but with class boundaries that ENNC must tile with prototypes: the four unused dims spread
    every region, so the classifier grows thousands of prototypes (about one per three patterns at 5 000).
    """
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, (patterns, 6))
    sites = rng.uniform(0.0, 1.0, (REGION_SITES, 2))
    site_class = rng.integers(0, 2, REGION_SITES)
    nearest = np.empty(patterns, dtype=np.int64)
    for start in range(0, patterns, 65536):  # bounded memory for any size
        block = x[start : start + 65536, None, :2] - sites[None]
        nearest[start : start + 65536] = np.argmin((block * block).sum(axis=2), axis=1)
    x[rng.random(patterns) < masked_share, 4:] = MASK_VALUE
    return x, site_class[nearest]


def ennc_vs_kmeans(
    x: np.ndarray, y: np.ndarray, cycles: int, seed: int = 0, threads: int | None = None
) -> dict[str, Any]:
    """ENNC (``cycles`` cycles) and scikit-learn's k-means (k = ENNC's final prototype count, at most ``cycles``
    Lloyd iterations from k random patterns) on the same patterns; per-cycle and per-iteration seconds and their
    ratio.

    The ratio is per cycle because k-means may converge before ``cycles`` iterations; a Lloyd iteration is the
    reference for "not much more work on the data than a Lloyd iteration". ``threads`` (None: as set) bounds the
    threads of both, torch's and k-means' OpenMP/BLAS pools alike.
    """
    start = time.perf_counter()
    model = ENNC(n_cycles=cycles, random_state=seed, n_threads=threads).fit(x, y)
    ennc_seconds = time.perf_counter() - start
    # Random patterns as the initial centres: k-means++ seeding costs O(N·k·log k), which is no Lloyd iteration.
    centres = x[np.random.default_rng(seed).choice(len(x), model.n_prototypes_, replace=False)]
    kmeans = KMeans(n_clusters=model.n_prototypes_, init=centres, max_iter=cycles, n_init=1, tol=0.0)
    with threadpool_limits(threads):
        start = time.perf_counter()
        kmeans.fit(x)
    kmeans_seconds = time.perf_counter() - start
    per_cycle = ennc_seconds / max(1, cycles)
    per_iteration = kmeans_seconds / max(1, int(kmeans.n_iter_))
    return {
        "patterns": len(x),
        "dims": int(x.shape[1]),
        "cycles": cycles,
        "classes": int(np.unique(y).size),
        "n_prototypes": int(model.n_prototypes_),
        "accuracy": round(float(model.score(x, y)), 4),
        "ennc_seconds": round(ennc_seconds, 3),
        "ennc_seconds_per_cycle": round(per_cycle, 5),
        "kmeans_seconds": round(kmeans_seconds, 3),
        "kmeans_iterations": int(kmeans.n_iter_),
        "kmeans_seconds_per_iteration": round(per_iteration, 5),
        "ratio": round(per_cycle / per_iteration, 3),
    }


def bench_ennc(
    patterns: int = 100_000,
    cycles: int = 250,
    phase1_tuples: int = 1_000_000,
    seed: int = 0,
    region_size: int = 20_000,
    threads: int | None = None,
) -> dict[str, Any]:
    """ENNC against scikit-learn's k-means (:func:`ennc_vs_kmeans`) on CMOMMT states and on
    :func:`region_patterns`, and ENNC-QL phase 1 on many tuples.

    The CMOMMT patterns are standardized collaborative states of one action (East) from random exploration with
    their first-iteration Q-target classes, exactly what phase 1 trains one classifier on (a few hundred
    prototypes); their figures are the top-level keys. ``region_size`` patterns of :func:`region_patterns` (0
    skips them) make ENNC grow thousands of prototypes; their figures are under ``"regions"``. ``threads`` as in
    :func:`ennc_vs_kmeans` (1 gives steadier figures on busy shared cores).
    """
    out: dict[str, Any] = {"benchmark": "ennc"}
    total = 2 + (1 if region_size else 0) + (2 if phase1_tuples else 0)
    with ProgressBar("bench ennc", total=total, unit="phases") as bar:
        bar.show(status=f"exploring for {patterns:,} patterns")
        sample = cmommt_experience(patterns, seed, action=2)
        x = sample.state / standard_scale(sample.state)
        y = to_classes(np.where(sample.done, sample.reward, 0.0), Phase1Config())
        bar.mark(f"{len(x):,} patterns, {np.unique(y).size} classes", n=1)
        bar.show(status=f"CMOMMT: ENNC {cycles} cycles, then k-means")
        out.update(ennc_vs_kmeans(x, y, cycles, seed, threads))
        bar.mark(f"CMOMMT: {out['n_prototypes']} prototypes, ratio {out['ratio']:.2f}", n=2)
        if region_size:
            bar.show(status=f"regions: {region_size:,} patterns, ENNC {cycles} cycles, then k-means")
            out["regions"] = ennc_vs_kmeans(*region_patterns(region_size, seed), cycles, seed, threads)
            bar.mark(
                f"regions: {out['regions']['n_prototypes']} prototypes, ratio {out['regions']['ratio']:.2f}",
                n=bar.n + 1,
            )
        if phase1_tuples:
            bar.show(status=f"exploring for {phase1_tuples:,} phase-1 tuples")
            big = cmommt_experience(phase1_tuples, seed)
            bar.mark(f"{len(big):,} phase-1 tuples", n=bar.n + 1)
            bar.show(status="phase 1, one iteration")
            start = time.perf_counter()
            result = phase1(big, N_ACTIONS, Phase1Config(max_iterations=1, n_cycles=cycles), seed=seed)
            out["phase1_tuples"] = phase1_tuples
            out["phase1_seconds"] = round(time.perf_counter() - start, 3)
            out["phase1_prototypes_per_action"] = [int(s) for s in result.discretization.sizes()]
            bar.mark(f"phase 1 on {phase1_tuples:,} tuples: {out['phase1_seconds']:.1f} s", n=bar.n + 1)
    out["target"] = {"ratio": 2.0, "phase1_seconds": 60.0}
    out["torch_threads"] = threads or torch.get_num_threads()
    out["meets_target"] = {
        "ratio": out["ratio"] <= 2.0 and out.get("regions", out)["ratio"] <= 2.0,
        "phase1_seconds": out.get("phase1_seconds", np.inf) <= 60.0,
    }
    return out


def _ennc_row(name: str, f: dict[str, Any]) -> str:
    return (
        f"{name:>7}: {f['patterns']} x {f['dims']}, {f['n_prototypes']} prototypes, ENNC {f['ennc_seconds']:.2f} s "
        f"({f['ennc_seconds_per_cycle'] * 1e3:.2f} ms/cycle), k-means {f['kmeans_seconds']:.2f} s "
        f"({f['kmeans_iterations']} it, {f['kmeans_seconds_per_iteration'] * 1e3:.2f} ms/it), ratio {f['ratio']:.2f}"
    )


def ennc_table(out: dict[str, Any]) -> str:
    rows = [_ennc_row("CMOMMT", out)] + ([_ennc_row("regions", out["regions"])] if "regions" in out else [])
    met = "met" if out["meets_target"]["ratio"] else "NOT met"
    table = "\n".join(rows) + f"\nENNC cycle / Lloyd iteration at equal k: target <= 2 ({met})"
    if "phase1_seconds" in out:
        met = "met" if out["meets_target"]["phase1_seconds"] else "NOT met"
        table += (
            f"\nENNC-QL phase 1 on {out['phase1_tuples']} tuples: {out['phase1_seconds']:.1f} s (target <= 60 s: {met})"
        )
    return table
