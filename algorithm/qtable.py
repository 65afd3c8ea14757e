"""Tabular Q-learning over per-action discretizations (ENNC-QL phase 2, VQQL).

A table is a flat vector over the concatenated cells of a :class:`~algorithm.discretization.Discretization`;
``Q[cells[n, a]]`` is Q(s_n, a). Per-robot tables (option 2) are rows of a (R, Σ P_a) array.

Update (paper Eq. 1): Q(s,a) ← (1−α)·Q(s,a) + α·(r + γ·max_b Q(s′,b)), with no bootstrap when s′ is terminal.
A batch may hit one cell c times; it is then updated as c sequential steps towards the mean target of those
tuples, Q ← Q + (1 − (1−α)^c)·(mean target − Q), which equals Eq. 1 exactly when c = 1.
"""

from __future__ import annotations

import numpy as np


def q_targets(
    table: np.ndarray, next_cells: np.ndarray, rewards: np.ndarray, dones: np.ndarray, gamma: float
) -> np.ndarray:
    """(N,) r + γ·max_b Q(s′, b), or r where ``dones``; ``table`` (Σ P_a,), ``next_cells`` (N, L)."""
    bootstrap = table[next_cells].max(axis=1)
    return np.where(dones, rewards, rewards + gamma * bootstrap).astype(np.float64)


def q_update(
    table: np.ndarray,
    visits: np.ndarray,
    cells: np.ndarray,
    targets: np.ndarray,
    alpha: float,
) -> None:
    """Move ``table[cells]`` towards ``targets`` in place and count the visits.

    ``table`` (Σ P_a,) float, ``visits`` (Σ P_a,) integer, ``cells`` (N,) the cell of (s, a) for each tuple.
    """
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"alpha must lie in (0, 1], got {alpha}")
    counts = np.bincount(cells, minlength=table.size)
    hit = np.nonzero(counts)[0]
    if hit.size == 0:
        return
    sums = np.bincount(cells, weights=targets, minlength=table.size)
    mean_target = sums[hit] / counts[hit]
    step = 1.0 - (1.0 - alpha) ** counts[hit]
    table[hit] += (step * (mean_target - table[hit])).astype(table.dtype)
    visits[hit] += counts[hit].astype(visits.dtype)


def greedy(table: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(N,) argmax_a Q(s, a) (lowest action on a tie); ``table`` (Σ P_a,) or per-row (N, Σ P_a)."""
    if table.ndim == 1:
        return np.argmax(table[cells], axis=1)
    return np.argmax(np.take_along_axis(table, cells, axis=1), axis=1)


def merge_tables(tables: np.ndarray, visits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Visit-count-weighted mean of K tables (K, Σ P_a) and their summed visits; unvisited cells average evenly."""
    tables = np.asarray(tables, dtype=np.float64)
    weights = np.asarray(visits, dtype=np.float64)
    total = weights.sum(axis=0)
    merged = np.where(total > 0, (tables * weights).sum(axis=0) / np.maximum(total, 1.0), tables.mean(axis=0))
    return merged.astype(np.float32), total.astype(np.uint64)
