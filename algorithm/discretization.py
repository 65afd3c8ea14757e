"""Per-action nearest-prototype discretizations of a continuous state space.

ENNC-QL learns one discretization S_a per action a (the prototypes of the ENNC approximator Q̂_a, labels dropped)
[paper §2.2]; VQQL uses one codebook for every action, which is the same structure with the codebook repeated.
All L discretizations are stored concatenated, so that one flat vector of Σ_a P_a entries holds a whole Q table::

    disc = Discretization.from_per_action([protos_a0, protos_a1, ...], [labels_a0, labels_a1, ...])
    cells = disc.cells(states)          # (N, L) global cell index of each state under each action's prototypes
    q = table[cells]                    # (N, L) Q values, table being a flat (Σ P_a,) vector
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from algorithm._search import Searcher

_CHUNK = 16384


def nearest(points: np.ndarray, prototypes: np.ndarray) -> np.ndarray:
    """(N,) index of the nearest prototype (Euclidean; lowest index on a tie) for each row of ``points``.

    Brute force (a matmul per chunk), for one-off searches such as LBG's; :meth:`Discretization.cells` answers the
    many searches of learning and acting with a built index instead.
    """
    points = np.asarray(points, dtype=np.float64)
    prototypes = np.asarray(prototypes, dtype=np.float64)
    sq = np.einsum("pd,pd->p", prototypes, prototypes)
    out = np.empty(points.shape[0], dtype=np.int64)
    for start in range(0, points.shape[0], _CHUNK):
        chunk = points[start : start + _CHUNK]
        # |x - c|² = |c|² - 2 x·c + |x|²; the last term does not change the argmin.
        out[start : start + _CHUNK] = np.argmin(sq[None, :] - 2.0 * chunk @ prototypes.T, axis=1)
    return out


@dataclass(frozen=True, slots=True)
class Discretization:
    """L per-action prototype sets, concatenated; ``labels`` are the phase-1 Q values of each prototype."""

    prototypes: np.ndarray
    """(Σ P_a, d) float32."""
    labels: np.ndarray
    """(Σ P_a,) float32, Q̂_a of each prototype (initial values of the phase-2 tables [choice])."""
    offsets: np.ndarray
    """(L + 1,) int64; action a owns rows offsets[a]:offsets[a+1]."""
    scale: np.ndarray | None = None
    """(d,) float32 per-dimension scale of the metric: a state's cell is its nearest prototype under
    |(x − c) / scale|. None means plain Euclidean. ENNC-QL fits on standardized states (see
    :class:`~algorithm.phase1.Phase1Config`), so its discretizations carry the scale they were fitted with."""
    _index: tuple[Searcher, bool] | None = field(default=None, init=False, repr=False, compare=False)
    """The search index of :meth:`cells` and whether every action shares action 0's prototypes, built on first use."""

    def __post_init__(self) -> None:
        p = self.prototypes
        if p.ndim != 2 or p.shape[0] == 0:
            raise ValueError(f"prototypes must be a non-empty (P, d) array, got shape {p.shape}")
        if self.labels.shape != (p.shape[0],):
            raise ValueError(f"labels must have shape {(p.shape[0],)}, got {self.labels.shape}")
        o = self.offsets
        if o.ndim != 1 or o.size < 2 or o[0] != 0 or o[-1] != p.shape[0] or np.any(np.diff(o) < 1):
            raise ValueError("offsets must start at 0, end at P and give every action at least one prototype")
        if not (np.isfinite(p).all() and np.isfinite(self.labels).all()):
            raise ValueError("prototypes and labels must be finite")
        if self.scale is not None and (
            self.scale.shape != (p.shape[1],) or not np.isfinite(self.scale).all() or (self.scale <= 0).any()
        ):
            raise ValueError(f"scale must be a positive finite ({p.shape[1]},) array")

    @classmethod
    def from_per_action(
        cls,
        prototypes: Sequence[np.ndarray],
        labels: Sequence[np.ndarray] | None = None,
        scale: np.ndarray | None = None,
    ) -> Discretization:
        """Concatenate per-action prototype arrays (and labels; zeros when omitted)."""
        sizes = [len(p) for p in prototypes]
        if labels is None:
            labels = [np.zeros(s, dtype=np.float32) for s in sizes]
        offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        return cls(
            prototypes=np.concatenate([np.asarray(p, dtype=np.float32) for p in prototypes]),
            labels=np.concatenate([np.asarray(lab, dtype=np.float32) for lab in labels]),
            offsets=offsets,
            scale=None if scale is None else np.asarray(scale, dtype=np.float32),
        )

    @classmethod
    def shared(cls, codebook: np.ndarray, n_actions: int) -> Discretization:
        """One codebook used by every action (VQQL)."""
        return cls.from_per_action([codebook] * n_actions)

    @property
    def n_actions(self) -> int:
        return int(self.offsets.size - 1)

    @property
    def dim(self) -> int:
        return int(self.prototypes.shape[1])

    @property
    def size(self) -> int:
        """Σ_a P_a, the length of a flat Q table."""
        return int(self.prototypes.shape[0])

    def sizes(self) -> np.ndarray:
        """(L,) P_a, prototypes per action."""
        return np.diff(self.offsets)

    def action_prototypes(self, action: int) -> np.ndarray:
        return self.prototypes[self.offsets[action] : self.offsets[action + 1]]

    def cells(self, states: np.ndarray) -> np.ndarray:
        """(N, L) int64 global cell of each state under each action's discretization: its nearest prototype
        (lowest index on a tie) under float64 squared distances, found by :mod:`algorithm._search`."""
        states = np.asarray(states)
        if states.ndim != 2 or states.shape[1] != self.dim:
            raise ValueError(f"states must have shape (N, {self.dim}), got {states.shape}")
        if not np.isfinite(states).all():
            raise ValueError("states must be finite")
        if self.scale is not None:
            states = states / self.scale
        searcher, shared = self._search_index()
        if shared:
            return self.offsets[:-1][None, :] + searcher.search(states)
        return searcher.search(states)

    def _search_index(self) -> tuple[Searcher, bool]:
        if self._index is None:
            shared = self.is_shared()
            actions = 1 if shared else self.n_actions
            # What a feature of 1 (a flag that is on) scales to, exactly as a float32 state's does in ``cells``.
            flags = np.ones(self.dim, np.float32) if self.scale is None else np.ones(self.dim, np.float32) / self.scale
            index = Searcher([self._scaled(a) for a in range(actions)], self.offsets, flags)
            # Frozen for callers; the index is derived from the fields, so caching it changes nothing they see.
            object.__setattr__(self, "_index", (index, shared))
        assert self._index is not None
        return self._index

    def _scaled(self, action: int) -> np.ndarray:
        protos = self.action_prototypes(action)
        return protos if self.scale is None else protos / self.scale

    def is_shared(self) -> bool:
        """Every action uses the same prototypes (a VQQL codebook): one nearest search serves all actions."""
        first = self.action_prototypes(0)
        return all(np.array_equal(first, self.action_prototypes(a)) for a in range(1, self.n_actions))

    def carry_over(self, old: Discretization, old_table: np.ndarray) -> np.ndarray:
        """Q values of ``old_table`` (…, old.size) moved onto this discretization.

        Each new prototype inherits the value of the nearest old prototype of the same action, so learning
        continues when a refit replaces the discretization (design: "Q values carry over").
        """
        if old.n_actions != self.n_actions or old.dim != self.dim:
            raise ValueError("discretizations differ in actions or state dimension")
        source = np.empty(self.size, dtype=np.int64)
        for a in range(self.n_actions):
            # Measured in the old discretization's metric: the old cell a new prototype falls into.
            new_a = self.action_prototypes(a) if old.scale is None else self.action_prototypes(a) / old.scale
            source[self.offsets[a] : self.offsets[a + 1]] = old.offsets[a] + nearest(new_a, old._scaled(a))
        return np.asarray(old_table)[..., source]
