"""Experience tuples ⟨robot, s, a, r, s′, done⟩ in columnar form."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, slots=True)
class Transitions:
    """N tuples, one row each; ``done`` marks terminal s′ (no bootstrap)."""

    robot: np.ndarray
    """(N,) int16 robot id within its arena."""
    state: np.ndarray
    """(N, d) float32."""
    action: np.ndarray
    """(N,) uint8 action index (a move of the formulation's action set)."""
    reward: np.ndarray
    """(N,) float32."""
    next_state: np.ndarray
    """(N, d) float32."""
    done: np.ndarray
    """(N,) bool."""

    def __len__(self) -> int:
        return int(self.action.shape[0])

    @property
    def dim(self) -> int:
        return int(self.state.shape[1])

    @classmethod
    def empty(cls, dim: int) -> Transitions:
        return cls(
            robot=np.zeros(0, np.int16),
            state=np.zeros((0, dim), np.float32),
            action=np.zeros(0, np.uint8),
            reward=np.zeros(0, np.float32),
            next_state=np.zeros((0, dim), np.float32),
            done=np.zeros(0, bool),
        )

    @classmethod
    def concat(cls, parts: Sequence[Transitions]) -> Transitions:
        if not parts:
            raise ValueError("concat needs at least one batch")
        return cls(
            robot=np.concatenate([p.robot for p in parts]),
            state=np.concatenate([p.state for p in parts]),
            action=np.concatenate([p.action for p in parts]),
            reward=np.concatenate([p.reward for p in parts]),
            next_state=np.concatenate([p.next_state for p in parts]),
            done=np.concatenate([p.done for p in parts]),
        )

    def take(self, index: np.ndarray | slice) -> Transitions:
        """The tuples at ``index``: copies for an index array, views for a slice."""
        return Transitions(
            robot=self.robot[index],
            state=self.state[index],
            action=self.action[index],
            reward=self.reward[index],
            next_state=self.next_state[index],
            done=self.done[index],
        )


class Batcher:
    """Tuples as they are made, handed on in batches of exactly ``size`` (the last one, at :meth:`flush`, shorter):
    the batches a whole stream's :meth:`Transitions.concat` would split into, without ever holding the stream.

    Usage (an actor's trial: each step's tuples in, full messages out)::

        batcher = Batcher(16384, send)       # send(Transitions) gets every full batch
        batcher.add(part)                    # as each step's tuples are made
        batcher.flush()                      # the rest, at the trial's end
    """

    def __init__(self, size: int, send: Callable[[Transitions], None]) -> None:
        if size < 1:
            raise ValueError(f"batch size must be at least 1, got {size}")
        self.size = size
        self._send = send
        self._parts: list[Transitions] = []
        self._held = 0

    def add(self, part: Transitions) -> None:
        self._parts.append(part)
        self._held += len(part)
        if self._held < self.size:
            return
        whole = Transitions.concat(self._parts)
        full = self._held - self._held % self.size
        for start in range(0, full, self.size):
            self._send(whole.take(slice(start, start + self.size)))
        rest = whole.take(slice(full, None))
        self._parts, self._held = ([rest] if len(rest) else []), len(rest)

    def flush(self) -> None:
        if self._held:
            self._send(Transitions.concat(self._parts))
        self._parts, self._held = [], 0
