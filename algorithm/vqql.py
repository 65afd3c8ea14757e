"""VQQL's state discretization: the Generalized Lloyd Algorithm (LBG) [paper; RoboCup-99].

Start from one codeword at the data centroid; split every codeword y into y·(1+ε) and y·(1−ε); run Lloyd
iterations (nearest assignment, centroid update) until the relative drop in distortion is below ``tol``; repeat
until K codewords. Empty cells are re-seeded next to the member of the cell with the largest distortion.

Usage::

    codebook = lbg(states, size=256, seed=0)      # (256, d)
"""

from __future__ import annotations

import logging

import numpy as np

from algorithm.discretization import nearest

log = logging.getLogger(__name__)


def _lloyd(
    x: np.ndarray, codebook: np.ndarray, tol: float, max_iter: int, rng: np.random.Generator
) -> tuple[np.ndarray, float]:
    previous = np.inf
    distortion = np.inf
    for _ in range(max_iter):
        cell = nearest(x, codebook)
        d2 = ((x - codebook[cell]) ** 2).sum(axis=1)
        distortion = float(d2.mean())
        counts = np.bincount(cell, minlength=len(codebook))
        sums = np.zeros_like(codebook)
        np.add.at(sums, cell, x)
        filled = counts > 0
        codebook = codebook.copy()
        codebook[filled] = sums[filled] / counts[filled, None]
        empty = np.nonzero(~filled)[0]
        if empty.size:
            # Re-seed each empty cell next to the worst-represented pattern of the most distorted cell.
            cell_distortion = np.bincount(cell, weights=d2, minlength=len(codebook))
            worst = int(np.argmax(cell_distortion))
            members = np.nonzero(cell == worst)[0]
            far = members[np.argsort(d2[members])[::-1][: empty.size]]
            jitter = rng.normal(0.0, 1e-6, (empty.size, x.shape[1]))
            codebook[empty] = x[np.resize(far, empty.size)] + jitter
        if previous < np.inf and (previous - distortion) <= tol * max(previous, 1e-300) and not empty.size:
            break
        previous = distortion
    return codebook, distortion


def lbg(
    x: np.ndarray,
    size: int,
    epsilon: float = 0.01,
    tol: float = 1e-3,
    max_iter: int = 100,
    seed: int | None = None,
) -> np.ndarray:
    """A codebook of ``size`` codewords (a power of two) for the rows of ``x``."""
    if size < 1 or size & (size - 1):
        raise ValueError(f"size must be a power of two, got {size}")
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] < size:
        raise ValueError(f"need a (N, d) array with N >= size={size}, got shape {x.shape}")
    rng = np.random.default_rng(seed)
    codebook = x.mean(axis=0, keepdims=True)
    while len(codebook) < size:
        codebook = np.concatenate([codebook * (1.0 + epsilon), codebook * (1.0 - epsilon)])
        # A codeword at the origin splits into two copies of itself: nudge the second copy.
        half = len(codebook) // 2
        same = np.all(codebook[:half] == codebook[half:], axis=1)
        codebook[half:][same] += rng.normal(0.0, epsilon, (int(same.sum()), x.shape[1]))
        codebook, distortion = _lloyd(x, codebook, tol, max_iter, rng)
        log.debug("lbg: %d codewords, distortion %.4g", len(codebook), distortion)
    return codebook
