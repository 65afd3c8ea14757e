"""The static drawings the views are read against: the north-up flip, the colour key, the prototype views' frames.

Imports Rerun: only :mod:`monitor.rerun_monitor` uses it.
"""

from __future__ import annotations

import itertools

import numpy as np
import rerun as rr

from monitor import geometry, paths, style
from sim.actions import ActionSet

NORTH_UP = rr.Transform3D(mat3x3=[[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]])
"""Mirrors y, logged at each drawing root (see :mod:`monitor.paths`): Rerun's 2-D views draw +y downwards."""

MARKER_RADIUS = rr.components.Radius.ui_points(4.0)
"""Markers in UI points (negative radii in Rerun) stay visible at any zoom of a 2000-unit arena."""
PROTOTYPE_RADIUS = rr.components.Radius.ui_points(3.0)
_THIN = rr.components.Radius.ui_points(0.5)
_BAR = rr.components.Radius.ui_points(5.0)
_Q_BAR_STEPS = 32

# The key is laid out in its own 10 x 8 box (layout.KEY_BOUNDS), y running down; the viewer writes a point's label
# centred below it, in the point's colour: robot and sensing range share the first row (short labels), each target
# colour has a row, and the Q bar spans x = 1.5..8.5 with its ends labelled.
_KEY_ENTRIES = {
    "robot": ((2.0, 0.9), style.rgba(style.ROBOT), MARKER_RADIUS, "robot"),
    # Labelled by a dot at the disk's rim: a label takes its point's colour, and the disk's is translucent.
    "sensing": ((7.4, 1.5), style.rgba(style.ROBOT), _THIN, "sensing range"),
    "observed": ((5.0, 3.0), style.rgba(style.OBSERVED), MARKER_RADIUS, "target, observed"),
    "unobserved": ((5.0, 4.7), style.rgba(style.UNOBSERVED), MARKER_RADIUS, "target, unobserved"),
}
_KEY_DISK = ((7.4, 0.9), 0.6)
"""Centre and radius of the key's sensing disk."""
_Q_BAR_Y = 6.6
_Q_BAR_ENDS = (1.5, 8.5)


def key(q_scale: bool) -> list[tuple[str, rr.Points2D | rr.LineStrips2D]]:
    """(path, archetype) of the key's static entries: what the arena colours mean and, for ``q_scale``, the
    prototype colour bar (its ends are labelled by :func:`q_ends` with each policy's Q range)."""
    entries: list[tuple[str, rr.Points2D | rr.LineStrips2D]] = [
        (
            f"{paths.KEY}/{name}",
            rr.Points2D([position], radii=radius, colors=color, labels=label, show_labels=True),
        )
        for name, (position, color, radius, label) in _KEY_ENTRIES.items()
    ]
    center, radius = _KEY_DISK
    disk = rr.Points2D([center], radii=radius, colors=style.rgba(style.ROBOT, style.SENSING_ALPHA))
    entries.append((f"{paths.KEY}/sensing_disk", disk))
    if q_scale:
        edges = np.linspace(*_Q_BAR_ENDS, _Q_BAR_STEPS + 1)
        strips = [[[a, _Q_BAR_Y], [b, _Q_BAR_Y]] for a, b in itertools.pairwise(edges)]
        colors = geometry.colormap(np.linspace(0.0, 1.0, _Q_BAR_STEPS))
        entries.append((paths.KEY_Q_BAR, rr.LineStrips2D(strips, radii=_BAR, colors=colors)))
    return entries


def q_ends(lo: float, hi: float) -> rr.Points2D:
    """The Q values at the ends of the key's colour bar."""
    return rr.Points2D(
        [[x, _Q_BAR_Y] for x in _Q_BAR_ENDS],
        radii=_THIN,
        colors=style.rgba(style.LIGHT_GREY),
        labels=[f"Q {lo:.2g}", f"Q {hi:.2g}"],
        show_labels=True,
    )


def prototype_frame(
    action: int, sensing_range: float, actions: ActionSet
) -> list[tuple[str, rr.LineStrips2D | rr.Arrows2D]]:
    """(path, archetype) of what the view of ``action``'s prototypes is read against, in arena units around the
    robot: the dx = 0 and dy = 0 axes, the sensing circle (targets in view lie inside it), and an arrow in the
    action's direction of motion in the action set ``actions``'s frame (the world's, or the target frame the
    prototypes of a target-frame state are drawn in)."""
    frame = f"{paths.prototypes_of(action)}/{paths.PROTOTYPE_FRAME}"
    reach = geometry.PROTOTYPE_REACH * sensing_range
    axes = [np.array([[-reach, 0.0], [reach, 0.0]]), np.array([[0.0, -reach], [0.0, reach]])]
    axes.append(geometry.circle(sensing_range))
    heading = 0.5 * sensing_range * actions.directions[action]
    return [
        (f"{frame}/axes", rr.LineStrips2D(axes, radii=_THIN, colors=style.rgba(style.MID_GREY), draw_order=0.0)),
        (f"{frame}/heading", rr.Arrows2D(vectors=[heading], radii=_THIN, colors=style.rgba(style.LIGHT_GREY))),
    ]
