"""Tabular Q-learning over per-action discretizations (ENNC-QL phase 2, VQQL).

A table is a flat vector over the concatenated cells of a :class:`~algorithm.discretization.Discretization`;
``Q[cells[n, a]]`` is Q(s_n, a). Per-robot tables (option 2) are rows of a (R, Σ P_a) array.

Update (paper Eq. 1): Q(s,a) ← (1−α)·Q(s,a) + α·(r + γ·max_b Q(s′,b)), with no bootstrap when s′ is terminal.
A batch may hit one cell c times; it is then updated as c sequential steps towards the mean target of those
tuples, Q ← Q + (1 − (1−α)^c)·(mean target − Q), which equals Eq. 1 exactly when c = 1.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit


def q_targets(bootstrap: np.ndarray, rewards: np.ndarray, dones: np.ndarray, gamma: float) -> np.ndarray:
    """(N,) Eq. 1's target r + γ·max_b Q(s′, b), or r where ``dones``; ``bootstrap`` (N,) holds max_b Q(s′, b)."""
    return np.where(dones, rewards, rewards + gamma * bootstrap).astype(np.float64)


def q_update(
    table: np.ndarray,
    visits: np.ndarray,
    cells: np.ndarray,
    targets: np.ndarray,
    alpha: float,
    alpha_floor: float | None = None,
) -> None:
    """Move ``table[cells]`` towards ``targets`` in place and count the visits.

    ``table`` (Σ P_a,) float, ``visits`` (Σ P_a,) integer, ``cells`` (N,) the cell of (s, a) for each tuple.
    With ``alpha_floor`` the n-th visit of a cell steps by max(alpha_floor, 1 / (1/alpha − 1 + n)): a running mean
    of the cell's targets in which the initial value weighs 1/alpha − 1 samples, until the step reaches the floor
    (see :func:`step_sizes`).
    """
    if not 0.0 < alpha <= 1.0:
        raise ValueError(f"alpha must lie in (0, 1], got {alpha}")
    counts = np.bincount(cells, minlength=table.size)
    hit = np.nonzero(counts)[0]
    if hit.size == 0:
        return
    sums = np.bincount(cells, weights=targets, minlength=table.size)
    mean_target = sums[hit] / counts[hit]
    step = step_sizes(visits[hit], counts[hit], alpha, alpha_floor)
    table[hit] += (step * (mean_target - table[hit])).astype(table.dtype)
    visits[hit] += counts[hit].astype(visits.dtype)


def step_sizes(before: np.ndarray, count: np.ndarray, alpha: float, alpha_floor: float | None) -> np.ndarray:
    """Combined step of ``count`` sequential updates of a cell visited ``before`` times, towards their mean target.

    Constant α: 1 − (1 − α)^c, which equals Eq. 1 exactly when c = 1. Decaying (``alpha_floor``): the k-th step is
    α_k = 1 / (w + k) with w = 1/α − 1 until it reaches the floor, and the product of the (1 − α_k) telescopes, so
    the combined step is exact for the running-mean part and 1 − (1 − floor)^c′ for the c′ steps at the floor.

    >>> step_sizes(np.array([0, 9, 10]), np.array([1, 1, 10]), 0.1, 0.01).round(4).tolist()
    [0.1, 0.0526, 0.3448]
    """
    count = np.asarray(count, np.float64)
    if alpha_floor is None:
        return 1.0 - (1.0 - alpha) ** count
    w = 1.0 / alpha - 1.0
    before = np.asarray(before, np.float64)
    last_decaying = np.floor(1.0 / alpha_floor - w)  # the last visit whose 1 / (w + k) is still above the floor
    decaying = np.clip(last_decaying - before, 0.0, count)
    kept = (w + before) / (w + before + decaying)
    return 1.0 - kept * (1.0 - alpha_floor) ** (count - decaying)


@njit(cache=True)
def n_step_targets(
    trial_rows: np.ndarray,  # (N,) int64: each tuple's robot in the trial's queues
    cells: np.ndarray,  # (N,) int64: the flat table index of each tuple's (s, a)
    rewards: np.ndarray,  # (N,) float64
    bootstrap: np.ndarray,  # (N,) float64: max_b Q(s′, b)
    ends: np.ndarray,  # (N,) bool: the robot's trial ends with this tuple
    dones: np.ndarray,  # (N,) bool: ... terminally (no bootstrap)
    gamma: float,
    queue_cells: np.ndarray,  # in/out (rows, n) int64: each robot's decisions whose targets are not complete yet
    queue_rewards: np.ndarray,  # in/out (rows, n) float64: their rewards
    queue_length: np.ndarray,  # in/out (rows,) int64
    out_cells: np.ndarray,  # out (N · n,) int64: the cells of the targets completed now ...
    out_targets: np.ndarray,  # out (N · n,) float64: ... and the targets
) -> int:
    """Queue each tuple behind its robot's earlier ones and complete the n-step targets it makes known: the oldest
    one once a robot holds n, every held one where its trial ends (r_j + γ r_j+1 + … down to the last reward, then
    γ·bootstrap unless terminal). Returns how many targets were completed. With n = 1 the targets are Eq. 1's."""
    n = queue_cells.shape[1]
    k = 0
    for t in range(trial_rows.shape[0]):
        r = trial_rows[t]
        length = queue_length[r]
        queue_cells[r, length] = cells[t]
        queue_rewards[r, length] = rewards[t]
        length += 1
        if ends[t]:
            g = 0.0 if dones[t] else bootstrap[t]
            for j in range(length - 1, -1, -1):
                g = queue_rewards[r, j] + gamma * g
                out_cells[k] = queue_cells[r, j]
                out_targets[k] = g
                k += 1
            length = 0
        elif length == n:
            g = bootstrap[t]
            for j in range(n - 1, -1, -1):
                g = queue_rewards[r, j] + gamma * g
            out_cells[k] = queue_cells[r, 0]
            out_targets[k] = g
            k += 1
            for j in range(n - 1):
                queue_cells[r, j] = queue_cells[r, j + 1]
                queue_rewards[r, j] = queue_rewards[r, j + 1]
            length = n - 1
        queue_length[r] = length
    return k


def row_best(tables: np.ndarray, rows: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) max_a and (N,) argmax_a of ``tables[rows[n], cells[n, a]]``, ``tables`` (R, Σ P_a), as numpy's max and
    argmax give them (the lowest action on a tie; a NaN wins, the first one). One pass instead of gathering an
    (N, L) array and reducing it twice: these were 6 % of a phase-2 slice."""
    flat = np.ascontiguousarray(tables).reshape(-1)
    best = np.empty(len(cells), flat.dtype)
    action = np.empty(len(cells), np.int64)
    _row_best(flat, tables.shape[1], np.asarray(rows, np.int64), np.asarray(cells, np.int64), best, action)
    return best, action


@njit(cache=True)
def _row_best(
    flat: np.ndarray, size: int, rows: np.ndarray, cells: np.ndarray, best: np.ndarray, action: np.ndarray
) -> None:
    for n in range(cells.shape[0]):
        base = rows[n] * size
        top = flat[base + cells[n, 0]]
        arg = 0
        for a in range(1, cells.shape[1]):
            v = flat[base + cells[n, a]]
            if v > top or (v != v and top == top):
                top = v
                arg = a
        best[n] = top
        action[n] = arg


def merge_increments(
    tables: np.ndarray, visits: np.ndarray, increments: Sequence[tuple[int, np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    """Per-robot tables (R, Σ P_a) and visits after adding K increments ``(robot, change (Σ P_a,), visits (Σ P_a,))``.

    Each cell of a robot's table moves by the visit-weighted mean of the changes made to it: with one increment
    per robot this applies the change exactly; several actors learning one robot move each cell by the mean of
    their changes, weighted by how often each visited it. Cells no increment visited keep their value. Pure: the
    inputs are not modified.

    >>> changes = [(0, np.array([2.0, 0.0]), np.array([2, 0])), (0, np.array([4.0, 1.0]), np.array([6, 0]))]
    >>> t, v = merge_increments(np.zeros((1, 2)), np.zeros((1, 2), np.uint64), changes)
    >>> t.tolist(), v.tolist()
    ([[3.5, 0.0]], [[8, 0]])
    """
    tables = np.array(tables, np.float64)
    visits = np.array(visits, np.uint64)
    by_robot: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
    for robot, change, weight in increments:
        by_robot.setdefault(int(robot), []).append((np.asarray(change, np.float64), np.asarray(weight, np.float64)))
    for robot, entries in by_robot.items():
        change = np.stack([c for c, _ in entries])
        weight = np.stack([w for _, w in entries])
        total = weight.sum(axis=0)
        visited = total > 0
        tables[robot, visited] += (change * weight).sum(axis=0)[visited] / total[visited]
        visits[robot] += total.astype(np.uint64)
    return tables, visits
