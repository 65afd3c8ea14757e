"""The actor's policy client (Acme's ``VariableClient``): keeps the newest broadcast and adopts it between trials.

Usage (``offer`` from the transport's thread, ``adopt`` from the actor's loop)::

    client = PolicyClient(n_robots=10, phase2=Phase2Config(), tracker=IncrementTracker(learn), formulation=f)
    client.offer(update)                   # newest version wins; older ones, and other formulations, are ignored
    update = client.take()                 # None while nothing newer than the adopted version has come
    agent = client.adopt(update, agent)    # the agent over the new tables
"""

from __future__ import annotations

import dataclasses
import logging
import threading

import numpy as np

from actors.increments import IncrementTracker
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.wire import formulation_mismatch, policy_from_update
from protocol import PolicyUpdate
from sim.formulation import Formulation

log = logging.getLogger(__name__)


class PolicyClient:
    def __init__(
        self, n_robots: int, phase2: Phase2Config, tracker: IncrementTracker, formulation: Formulation
    ) -> None:
        self.n_robots = n_robots
        self.formulation = formulation
        """The actor's own state, reward and action set: a broadcast over another formulation cannot be acted on."""
        self.refused = 0
        """Broadcasts refused because they are over another formulation than the actor's."""
        self.phase2 = phase2
        self.tracker = tracker
        self._lock = threading.Lock()
        self._newest: PolicyUpdate | None = None
        self.version = 0
        """Version of the adopted policy (0: none yet)."""
        self.adopted = 0

    def offer(self, update: PolicyUpdate) -> None:
        mismatch = self._mismatch(update)
        if mismatch:
            with self._lock:
                self.refused += 1
                first = self.refused == 1
            # Every broadcast would say it again: the first is logged, all are counted (status: policies_refused).
            if first:
                log.error(
                    "policy version %d is refused: %s (is the learner started with the same --formulation?)",
                    update.version,
                    mismatch,
                )
            return
        with self._lock:
            if update.version > max(self.version, 0 if self._newest is None else self._newest.version):
                self._newest = update

    def _mismatch(self, update: PolicyUpdate) -> str:
        """What makes ``update`` unusable here ("" if nothing): another formulation, or a state dimension that is
        not its featurizer's (the wire checks only that the names are well formed)."""
        own = self.formulation
        mismatch = formulation_mismatch(own, update)
        dim = int(update.prototypes.shape[1])
        if not mismatch and dim != own.dim:
            return f"its prototypes have {dim} dimensions, {own.featurizer.name} has {own.dim}"
        return mismatch

    def take(self) -> PolicyUpdate | None:
        """The newest broadcast if it is newer than the adopted one (once)."""
        with self._lock:
            update, self._newest = self._newest, None
        return None if update is None or update.version <= self.version else update

    def adopt(self, update: PolicyUpdate, agent: TabularAgent | None) -> TabularAgent:
        """The agent over ``update``'s tables, replacing ``agent``.

        Over the same cells, the learning of ``agent`` not yet handed in is kept on top of the broadcast tables;
        over new cells, the tracker starts afresh (the learner carries values over itself).
        """
        policy = policy_from_update(update, self.n_robots, self.formulation)
        if agent is not None and _same_discretization(agent.discretization, policy.discretization):
            # The same discretization object keeps the search indexes it built as states met them (≈ 0.1 s for
            # make run's frame9d policy): a broadcast every few seconds would otherwise build them all again.
            policy = dataclasses.replace(policy, discretization=agent.discretization)
        new = TabularAgent(policy, self.phase2)
        if agent is not None and _same_cells(agent.discretization, new.discretization):
            self.tracker.rebase(new, agent)
        else:
            self.tracker.reset(new)
        self.version = int(update.version)
        self.adopted += 1
        # The first one at INFO: the moment an actor stops exploring at random, which a user (and a test) waits for.
        (log.info if self.adopted == 1 else log.debug)("adopted policy version %d", self.version)
        return new


def _same_cells(a: Discretization, b: Discretization) -> bool:
    return a.prototypes.shape == b.prototypes.shape and bool(np.array_equal(a.prototypes, b.prototypes))


def _same_discretization(a: Discretization, b: Discretization) -> bool:
    """Every field equal: either object searches and labels states alike."""
    if a.scale is None or b.scale is None:
        same_scale = a.scale is None and b.scale is None
    else:
        same_scale = bool(np.array_equal(a.scale, b.scale))
    return (
        _same_cells(a, b)
        and same_scale
        and bool(np.array_equal(a.offsets, b.offsets))
        and bool(np.array_equal(a.labels, b.labels))
    )
