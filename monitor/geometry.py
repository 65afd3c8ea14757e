"""Pure array helpers behind the views: who observes what, the arena outline, prototype projection and Q colours."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sim.features import Featurizer

COLORMAP = "viridis"

PROTOTYPE_REACH = 1.2
"""Half-width of a prototype view in sensing ranges, as in ``ennc_ql.figures.policy_figure``: the (dx, dy) of a
target in view lie within one sensing range; the masked value (nothing in view) lies far outside and is not shown."""


def observed_targets(robot_pos: np.ndarray, target_pos: np.ndarray, sensing_range: float) -> np.ndarray:
    """(n,) bool: target j lies within ``sensing_range`` (inclusive, as in ``sim``) of at least one robot.

    ``robot_pos`` (m, 2), ``target_pos`` (n, 2), arena units.
    """
    robots = np.asarray(robot_pos, dtype=np.float64).reshape(-1, 2)
    targets = np.asarray(target_pos, dtype=np.float64).reshape(-1, 2)
    d2 = ((robots[:, None, :] - targets[None, :, :]) ** 2).sum(axis=-1)
    return np.asarray((d2 <= sensing_range * sensing_range).any(axis=0))


def circle(radius: float, segments: int = 128) -> np.ndarray:
    """(segments + 1, 2) closed polyline of the circle of ``radius`` around the origin."""
    angle = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    return radius * np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def view_subject(featurizer: Featurizer | None) -> str:
    """What :func:`project_2d` shows of ``featurizer``'s prototypes, for a caption."""
    if featurizer is not None and featurizer.frame == "target":
        return "where the second target in view lies, in the nearest target's frame"
    return "where the nearest target in view lies, seen from the robot"


def project_2d(prototypes: np.ndarray, featurizer: Featurizer | None = None) -> np.ndarray:
    """(p, 2) view coordinates of (p, d) prototypes: two of their features, the featurizer's
    :attr:`~sim.features.Featurizer.view` columns (the first two without one; d = 1 gets y = 0).

    Features are kept rather than a PCA because they mean something in the arena and stay the same axes from one
    policy version to the next: for ``collab6d`` they are (dx, dy) to the nearest target in view, for ``local2d``
    (dx, dy) to the tracked target, so each action's panel shows where the target lies relative to the robot,
    coloured by the value of that move. A PCA's axes would rotate and flip with every refit, and an animation over
    ``policy_version`` would jump.
    """
    points = np.asarray(prototypes, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] < 1:
        raise ValueError(f"prototypes must have shape (p, d) with d >= 1, got {points.shape}")
    if points.shape[1] == 1:
        return np.concatenate([points, np.zeros_like(points)], axis=1)
    columns = (0, 1) if featurizer is None else featurizer.view
    return points[:, list(columns)].copy()


def q_range(q_values: Sequence[np.ndarray]) -> tuple[float, float]:
    """(min, max) of the finite Q values of all actions together; (0, 0) when there is none."""
    arrays = [np.asarray(q, dtype=np.float64).reshape(-1) for q in q_values]
    finite = np.concatenate([a[np.isfinite(a)] for a in arrays]) if arrays else np.zeros(0)
    return (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)


def colormap(values: np.ndarray) -> np.ndarray:
    """(n, 4) uint8 RGBA of ``COLORMAP`` at ``values`` in [0, 1] (NaN takes the low end)."""
    import matplotlib

    cmap = matplotlib.colormaps[COLORMAP]
    scaled = np.asarray(values, dtype=np.float64).reshape(-1)
    return np.asarray(cmap(np.nan_to_num(scaled, nan=0.0), bytes=True), dtype=np.uint8).reshape(-1, 4)


def q_colors(q_values: Sequence[np.ndarray]) -> list[np.ndarray]:
    """(p_k, 4) uint8 RGBA per action, ``COLORMAP`` normalised over :func:`q_range` of all actions together.

    One range for all actions keeps colours comparable across the panels; a constant Q gets the middle colour.
    """
    lo, hi = q_range(q_values)
    span = hi - lo
    colors = []
    for q in q_values:
        a = np.asarray(q, dtype=np.float64).reshape(-1)
        colors.append(colormap((a - lo) / span if span > 0 else np.full_like(a, 0.5)))
    return colors
