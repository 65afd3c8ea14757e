"""Pure helpers behind the views."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

from monitor.geometry import circle, observed_targets, project_2d, q_colors
from sim.features import FEATURIZER_REGISTRY


def test_observed_targets_use_the_inclusive_sensing_range() -> None:
    robots = np.array([[0.0, 0.0], [500.0, 0.0]])
    targets = np.array([[150.0, 0.0], [150.1, 0.0], [500.0, -149.0], [-400.0, 300.0]])
    assert observed_targets(robots, targets, 150.0).tolist() == [True, False, True, False]


def test_observed_targets_with_no_robot_sees_nothing() -> None:
    assert not observed_targets(np.zeros((0, 2)), np.zeros((3, 2)), 150.0).any()


def test_circle_is_closed_on_the_radius() -> None:
    points = circle(1000.0, segments=64)
    assert points.shape == (65, 2)
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 1000.0)
    np.testing.assert_allclose(points[0], points[-1], atol=1e-9)


def test_projection_keeps_the_first_two_features() -> None:
    protos = np.arange(18.0).reshape(3, 6)
    np.testing.assert_array_equal(project_2d(protos), protos[:, :2])
    np.testing.assert_array_equal(project_2d(np.array([[1.0], [2.0]])), [[1.0, 0.0], [2.0, 0.0]])
    with pytest.raises(ValueError, match=r"\(p, d\)"):
        project_2d(np.zeros(4))


def test_states_in_the_target_frame_are_drawn_at_the_second_target() -> None:
    # frame9d: (distance to the nearest target, the furthest target's x, y in its frame, ...); the distance alone is
    # no position, the furthest target's offset in the frame is.
    protos = np.array([[120.0, 30.0, 40.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    np.testing.assert_array_equal(project_2d(protos, FEATURIZER_REGISTRY["frame9d"]), [[30.0, 40.0]])
    np.testing.assert_array_equal(project_2d(protos[:, :8], FEATURIZER_REGISTRY["shared8d"]), [[120.0, 30.0]])


def test_q_colors_share_one_range_across_actions() -> None:
    low, high = q_colors([np.array([-1.0, 0.0]), np.array([1.0])])
    assert low.shape == (2, 4) and high.shape == (1, 4) and low.dtype == np.uint8
    viridis = matplotlib.colormaps["viridis"]
    np.testing.assert_array_equal(low[0], viridis(0.0, bytes=True))
    np.testing.assert_array_equal(low[1], viridis(0.5, bytes=True))
    np.testing.assert_array_equal(high[0], viridis(1.0, bytes=True))
    (same,) = q_colors([np.full(3, 2.0)])
    assert (same == same[0]).all()  # a constant Q gets one (middle) colour
