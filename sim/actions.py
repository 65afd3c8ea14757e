"""Action sets by name: what a learned policy's action indices mean.

A formulation (:class:`sim.features.Formulation`) names its action set, and so does every policy broadcast: an actor
must not act on a table whose action 3 means another move than its own action 3. One set so far::

    ACTION_SETS["compass"].moves     # ('N', 'NE', 'E', 'SE', 'S', 'SW', 'W', 'NW')
"""

from __future__ import annotations

from dataclasses import dataclass

from sim.controllers import COMPASS_NAMES


@dataclass(frozen=True, slots=True)
class ActionSet:
    name: str
    moves: tuple[str, ...]
    """The move of each action index, in index order."""


ACTION_SETS: dict[str, ActionSet] = {
    a.name: a
    for a in (
        # The eight compass headings, each held ``action_steps`` steps at the robot's speed [paper].
        ActionSet("compass", COMPASS_NAMES),
    )
}
"""Every action set by name."""
