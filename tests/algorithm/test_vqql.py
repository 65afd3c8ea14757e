"""The LBG codebook of VQQL."""

from __future__ import annotations

import numpy as np
import pytest

from algorithm.discretization import nearest
from algorithm.vqql import lbg


def distortion(x: np.ndarray, codebook: np.ndarray) -> float:
    return float(((x - codebook[nearest(x, codebook)]) ** 2).sum(axis=1).mean())


def test_codebook_finds_well_separated_clusters() -> None:
    rng = np.random.default_rng(0)
    centres = np.array([[0, 0], [10, 0], [0, 10], [10, 10]], dtype=float)
    x = np.concatenate([c + rng.normal(0, 0.3, (200, 2)) for c in centres])
    codebook = lbg(x, 4, seed=0)
    assert codebook.shape == (4, 2)
    # Every true centre has a codeword within 0.2 and every cluster is one cell.
    assert np.abs(codebook[nearest(centres, codebook)] - centres).max() < 0.2
    assert len(set(nearest(centres, codebook))) == 4


def test_distortion_falls_as_the_codebook_grows_and_no_cell_is_empty() -> None:
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.normal(0, 1, (1500, 3)), np.full((500, 3), 1000.0)])  # a mask-like spike
    previous = np.inf
    for size in (1, 2, 8, 32):
        codebook = lbg(x, size, seed=1)
        d = distortion(x, codebook)
        assert d < previous
        previous = d
        assert np.bincount(nearest(x, codebook), minlength=size).min() > 0


@pytest.mark.parametrize("size", [0, 3, 12])
def test_sizes_must_be_powers_of_two(size: int) -> None:
    with pytest.raises(ValueError, match="power of two"):
        lbg(np.zeros((20, 2)), size)
