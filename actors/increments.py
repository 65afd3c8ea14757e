"""What of each learned robot's table the actor has handed in: a Q-table increment carries the change since then,
so none is lost when a broadcast overtakes it.

Usage::

    tracker = IncrementTracker(robots=(0, 1, 2))  # the robots the actor learns
    tracker.reset(agent)                          # a new discretization: nothing of it handed in yet
    for robot, change, visits in tracker.take(agent):
        msg = increment_message(header, robot=robot, change=change, visits=visits, offsets=offsets)
    tracker.rebase(new_agent, old_agent)          # a broadcast over the same cells: keep what is not handed in
"""

from __future__ import annotations

import numpy as np

from algorithm.agent import TabularAgent


class IncrementTracker:
    def __init__(self, robots: tuple[int, ...]) -> None:
        self.robots = list(robots)
        self._tables = np.zeros(0)
        self._visits = np.zeros(0, np.uint64)

    def reset(self, agent: TabularAgent) -> None:
        self._tables = agent.tables.copy()
        self._visits = agent.visits.copy()

    def take(self, agent: TabularAgent) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(robot, change, visits) of every learned robot whose table was visited since the last ``take``."""
        out = []
        for robot in self.robots:
            visits = agent.visits[robot] - self._visits[robot]
            if not visits.any():
                continue
            out.append((robot, agent.tables[robot] - self._tables[robot], visits))
            self._visits[robot] = agent.visits[robot]
            self._tables[robot] = agent.tables[robot]
        return out

    def rebase(self, new: TabularAgent, old: TabularAgent) -> None:
        """Put the learning not yet handed in on top of the merged tables of ``new`` (the broadcast may not hold our
        newest increments yet: they are in flight, and come back in a later broadcast)."""
        robots = self.robots
        new.tables[robots] += old.tables[robots] - self._tables[robots]
        new.visits[robots] = old.visits[robots]
        self._tables[robots] = new.template.tables[robots]
