"""The learner's policy state: discretization, per-robot tables and visits, pending increments, and the version.

Usage (thread-safe: every method takes the state's own lock)::

    state = PolicyState(n_robots=10, formulation=f, scenario="cmommt-v1", action_steps=5, method="...")
    state.adopt(discretization)            # after phase 1: tables from the labels, or carried over on a refit
    state.add_increment(msg)               # an actor's table change; False if it was over another discretization
    update = state.publish()               # merge what is pending, bump the version: the PolicyUpdate to broadcast
    state.current                          # the latest broadcast (late joiners get it)
    policy = state.policy()                # a snapshot for evaluation and the policy file
    arrays, meta = state.to_arrays()       # for a checkpoint (tables and the increments not merged yet)
    state.restore(arrays, meta, published) # continue from it, above every version ever broadcast
"""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.qtable import merge_increments
from algorithm.wire import increment_arrays, policy_update
from protocol import PolicyUpdate, QTableIncrement
from sim.formulation import Formulation


class PolicyState:
    def __init__(
        self,
        n_robots: int,
        formulation: Formulation,
        scenario: str,
        action_steps: int,
        method: str,
        team: bool = False,
        on_version: Callable[[int], None] | None = None,
    ) -> None:
        self.on_version = on_version
        """Called with each new version before anyone can see it (the learner persists its version mark there)."""
        self.n_robots = n_robots
        self.formulation = formulation
        """What the actors learn on (the policy file records it); its ``act_every`` is how often the evaluated and
        saved policy decides (None: ``action_steps``)."""
        self.scenario = scenario
        self.action_steps = action_steps
        self.method = method
        self.team = team
        """:meth:`policy` merges the robots' rows into one table (:meth:`algorithm.policy.Policy.team`)."""
        self._lock = threading.Lock()
        self._disc: Discretization | None = None
        self._disc_id = 0
        """Counts discretizations: an increment is merged only over the one it was learned on."""
        self._disc_of_version: dict[int, int] = {}
        self._tables = np.zeros((n_robots, 0))
        self._visits = np.zeros((n_robots, 0), np.uint64)
        self._version = 0
        self._pending: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = {}
        """(actor, robot) -> summed change and visits of the increments not merged yet."""
        self._current: PolicyUpdate | None = None
        self.increments = 0
        """Increments received (each sequence number once)."""
        self.stale_increments = 0
        """Of those, increments over another discretization than the current one: not merged
        (docs/reference/protocol.md §5)."""
        self.dropped_visits = 0
        """Visits acknowledged but in no table: those of stale increments (over a discretization no longer held)."""
        self.carried_visits = 0
        """Visits of the tables a refit carried over into its new cells' values (its visit counts start afresh): with
        the visits the tables and pending increments hold and the dropped ones, every visit acknowledged."""

    @property
    def version(self) -> int:
        with self._lock:
            return self._version

    @property
    def current(self) -> PolicyUpdate | None:
        with self._lock:
            return self._current

    @property
    def discretization(self) -> Discretization | None:
        with self._lock:
            return self._disc

    @property
    def fitted(self) -> bool:
        with self._lock:
            return self._disc is not None

    def adopt(self, disc: Discretization) -> None:
        """Take a new discretization: the first one's tables start from its labels; a later one (a refit) inherits
        the current values (pending increments merged first), each new prototype from the nearest old one, so no
        acknowledged experience is thrown away with the cells it was learned on."""
        with self._lock:
            if self._disc is None:
                tables = np.tile(disc.labels.astype(np.float64), (self.n_robots, 1))
            else:
                self._merge_pending()
                tables = disc.carry_over(self._disc, self._tables)
                self.carried_visits += int(self._visits.sum())
            self._disc = disc
            self._disc_id += 1
            self._tables = tables
            self._visits = np.zeros(tables.shape, np.uint64)

    def add_increment(self, msg: QTableIncrement) -> bool:
        """Queue an actor's change for the next merge; successive increments of one actor and robot add up."""
        with self._lock:
            self.increments += 1
            disc_id = self._disc_of_version.get(int(msg.policy_version))
            if disc_id != self._disc_id or msg.robot >= self.n_robots or msg.q.size != self._tables.shape[1]:
                self.stale_increments += 1  # over another discretization: its cells mean something else now
                self.dropped_visits += int(np.asarray(msg.visits, np.int64).sum())
                return False
            robot, change, visits = increment_arrays(msg)
            key = (msg.actor_id, robot)
            previous = self._pending.get(key)
            if previous is not None:
                change, visits = change + previous[0], visits + previous[1]
            self._pending[key] = (change, visits)
            return True

    def publish(self) -> PolicyUpdate:
        """Merge what is pending and return the next version's broadcast (also kept as ``current``)."""
        with self._lock:
            if self._disc is None:
                raise RuntimeError("no discretization yet: phase 1 has not run")
            self._merge_pending()
            if self.on_version is not None:
                self.on_version(self._version + 1)
            self._version += 1
            self._disc_of_version[self._version] = self._disc_id
            self._current = policy_update(self._policy(), self.scenario)
            return self._current

    def policy(self) -> Policy | None:
        """The acting policy, for evaluation and the policy file: robots decide every ``act_every`` steps, on one
        merged table if ``team``."""
        with self._lock:
            if self._disc is None:
                return None
            policy = self._policy()
        if self.team:
            policy = policy.team()
        every = self.formulation.act_every
        return policy if every is None else dataclasses.replace(policy, action_steps=every)

    def lag(self, latest_version: dict[str, int]) -> dict[str, int]:
        """Versions each actor's newest experience is behind the current policy."""
        with self._lock:
            return {actor: self._version - v for actor, v in latest_version.items()}

    def to_arrays(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Everything a checkpoint must hold for its acknowledgements to be kept: the tables, and the increments
        acknowledged but not merged yet."""
        with self._lock:
            keys = sorted(self._pending)
            meta = {
                "version": self._version,
                "disc_id": self._disc_id,
                "disc_of_version": _ranges(self._disc_of_version),
                "pending": [[actor, robot] for actor, robot in keys],
                "increments": self.increments,
                "stale_increments": self.stale_increments,
            }
            dropped = {
                "dropped_visits": np.array(self.dropped_visits, np.int64),
                "carried_visits": np.array(self.carried_visits, np.int64),
            }
            if self._disc is None:
                return dropped, meta
            arrays = {
                **dropped,
                "prototypes": self._disc.prototypes,
                "labels": self._disc.labels,
                "offsets": self._disc.offsets,
                "tables": self._tables,
                "visits": self._visits,
                "pending_change": np.array([self._pending[k][0] for k in keys]).reshape(len(keys), self._disc.size),
                "pending_visits": np.array([self._pending[k][1] for k in keys]).reshape(len(keys), self._disc.size),
            }
            if self._disc.scale is not None:
                arrays["scale"] = self._disc.scale
            return arrays, meta

    def restore(self, arrays: dict[str, np.ndarray], meta: dict[str, Any], published: int = 0) -> None:
        """Continue from a checkpoint. ``published`` is the highest version ever broadcast (the version mark, which
        may be past the checkpoint's): the restored tables go out as a version above both. Versions broadcast
        after the checkpoint were over its discretization, since a new one is checkpointed before its first
        broadcast, so increments stamped with them still merge."""
        with self._lock:
            saved = int(meta["version"])
            self._version = max(saved, published)
            self._disc_id = int(meta["disc_id"])
            self._disc_of_version = _unranges(meta["disc_of_version"])
            self.increments = int(meta["increments"])
            self.stale_increments = int(meta["stale_increments"])
            self.dropped_visits = int(arrays.get("dropped_visits", 0))
            self.carried_visits = int(arrays.get("carried_visits", 0))  # none in checkpoints of earlier versions
            if "prototypes" not in arrays:
                return
            self._disc = Discretization(arrays["prototypes"], arrays["labels"], arrays["offsets"], arrays.get("scale"))
            self._tables = arrays["tables"].astype(np.float64)
            self._visits = arrays["visits"].astype(np.uint64)
            for row, (actor, robot) in enumerate(meta["pending"]):
                self._pending[(str(actor), int(robot))] = (
                    arrays["pending_change"][row].astype(np.float64),
                    arrays["pending_visits"][row].astype(np.float64),
                )
            for version in range(saved + 1, self._version + 1):
                self._disc_of_version[version] = self._disc_id
            if self.on_version is not None:
                self.on_version(self._version + 1)
            self._version += 1
            self._disc_of_version[self._version] = self._disc_id
            self._current = policy_update(self._policy(), self.scenario)

    def _merge_pending(self) -> None:
        increments = [(robot, change, visits) for (_, robot), (change, visits) in self._pending.items()]
        if increments:
            self._tables, self._visits = merge_increments(self._tables, self._visits, increments)
        self._pending.clear()

    def _policy(self) -> Policy:
        assert self._disc is not None
        return Policy(
            formulation=self.formulation,
            discretization=self._disc,
            tables=self._tables.astype(np.float32),
            robot_table=np.arange(self.n_robots),
            action_steps=self.action_steps,
            visits=self._visits.copy(),
            version=self._version,
            method=self.method,
        )


def _ranges(disc_of_version: dict[int, int]) -> list[list[int]]:
    """{version: discretization} as [[first version, last version, discretization], ...] (runs of equal values)."""
    out: list[list[int]] = []
    for version in sorted(disc_of_version):
        disc = disc_of_version[version]
        if out and out[-1][1] == version - 1 and out[-1][2] == disc:
            out[-1][1] = version
        else:
            out.append([version, version, disc])
    return out


def _unranges(ranges: list[list[int]]) -> dict[int, int]:
    return {v: int(disc) for first, last, disc in ranges for v in range(int(first), int(last) + 1)}
