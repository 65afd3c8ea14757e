"""Conversions between the algorithm's types and the wire messages, both directions in one place.

The learner and the actors never build or unpack a message field by field themselves; they call these::

    update = policy_update(policy, scenario="cmommt-v1")                  # learner: Policy -> PolicyUpdate
    why = formulation_mismatch(formulation, update)                       # either end: "" or the part that differs
    policy = policy_from_update(update, n_robots=10, formulation=formulation)  # actor: PolicyUpdate -> Policy
    header = Header(actor_id="actor-0", incarnation=7, seq=5, policy_version=3)
    batch = experience_message(header, transitions, formulation)          # Transitions -> ExperienceBatch
    for seq, build in enumerate(experience_batches(transitions, 16384, formulation)):  # in messages of <= 16384
        batch = build(Header("actor-0", 7, seq, 3))                       #     tuples, each given its header when sent
    transitions = transitions_from_batch(batch)                           # learner: ExperienceBatch -> Transitions
    msg = increment_message(header, robot=2, change=change, visits=visits, offsets=disc.offsets)
    robot, change, visits = increment_arrays(msg)                         # learner: QTableIncrement -> arrays
    counters = status_counters(figures)                                   # a figures dataclass -> Status.counters
    figures = figures_from_counters(LearnerStatus, counters)              # and back (readers such as `up`)

Imports only the message definitions (no transport, no zenoh, no torch).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Mapping
from functools import partial
from typing import Any, Protocol, TypeVar

import numpy as np

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.transitions import Transitions
from protocol.messages import ExperienceBatch, Header, PolicyUpdate, QTableIncrement
from sim.formulation import Formulation

_U32_MAX = np.iinfo(np.uint32).max
F = TypeVar("F")


def _u32(counts: np.ndarray) -> np.ndarray:
    # Visit counts saturate on the wire instead of wrapping round.
    return np.minimum(counts, _U32_MAX).astype(np.uint32)


class _NamesFormulation(Protocol):
    """A message that names a formulation: :class:`ExperienceBatch` and :class:`PolicyUpdate`."""

    @property
    def featurizer(self) -> str: ...
    @property
    def reward_function(self) -> str: ...
    @property
    def action_set(self) -> str: ...


def formulation_mismatch(own: Formulation, msg: _NamesFormulation) -> str:
    """ "" if ``msg`` names the formulation ``own``, else its first part that differs, e.g. ``reward_function eq2,
    expected difference`` (fits a Reject's 64-character reason): both ends of the wire refuse another formulation
    with it, the learner an experience message, an actor a policy broadcast."""
    for part, theirs, mine in zip(
        ("featurizer", "reward_function", "action_set"),
        (msg.featurizer, msg.reward_function, msg.action_set),
        own.names,
        strict=True,
    ):
        if theirs != mine:
            return f"{part} {theirs}, expected {mine}"
    return ""


def policy_update(policy: Policy, scenario: str) -> PolicyUpdate:
    """The broadcast message of ``policy``: one table row per robot (robot i's row is ``tables[robot_table[i]]``)."""
    disc = policy.discretization
    tables = policy.tables[policy.robot_table]
    visits = np.zeros(tables.shape, np.uint64) if policy.visits is None else policy.visits[policy.robot_table]
    return PolicyUpdate(
        version=policy.version,
        scenario=scenario,
        featurizer=policy.formulation.featurizer.name,
        reward_function=policy.formulation.reward.name,
        action_set=policy.formulation.actions.name,
        action_steps=policy.action_steps,
        prototypes=disc.prototypes.astype(np.float32),
        labels=disc.labels.astype(np.float32),
        offsets=disc.offsets.astype(np.int64),
        robots=np.arange(policy.n_robots, dtype=np.int16),
        q_tables=tables.astype(np.float32),
        visits=_u32(visits),
        scale=np.ones(disc.dim, np.float32) if disc.scale is None else disc.scale.astype(np.float32),
    )


def policy_from_update(update: PolicyUpdate, n_robots: int, formulation: Formulation, method: str = "") -> Policy:
    """The acting policy of a broadcast over ``formulation`` (the receiver's own, which
    :func:`formulation_mismatch` found it names) for ``n_robots`` robots: robot i uses the update's row for robot i;
    robots the update does not name use the mean of its rows (with no visits)."""
    disc = Discretization(
        prototypes=np.array(update.prototypes),
        labels=np.array(update.labels),
        offsets=np.array(update.offsets),
        scale=np.array(update.scale),
    )
    tables = np.tile(np.asarray(update.q_tables, np.float32).mean(axis=0), (n_robots, 1))
    visits = np.zeros((n_robots, disc.size), np.uint64)
    for row, robot in enumerate(np.asarray(update.robots)):
        if robot < n_robots:
            tables[robot] = update.q_tables[row]
            visits[robot] = update.visits[row]
    return Policy(
        formulation=formulation,
        discretization=disc,
        tables=tables,
        robot_table=np.arange(n_robots),
        action_steps=int(update.action_steps),
        visits=visits,
        version=int(update.version),
        method=method,
    )


def experience_message(header: Header, transitions: Transitions, formulation: Formulation) -> ExperienceBatch:
    """One experience message of ``transitions``, made under ``formulation``. Building it validates it, so a tuple
    the learner would refuse (NaN, a wrong dtype) fails here, in the actor that made it, not on the wire."""
    return ExperienceBatch(
        actor_id=header.actor_id,
        incarnation=header.incarnation,
        seq=header.seq,
        policy_version=header.policy_version,
        featurizer=formulation.featurizer.name,
        reward_function=formulation.reward.name,
        action_set=formulation.actions.name,
        robot=transitions.robot,
        state=transitions.state,
        action=transitions.action,
        reward=transitions.reward,
        next_state=transitions.next_state,
        done=transitions.done,
    )


def experience_batches(
    transitions: Transitions, batch_size: int, formulation: Formulation
) -> Iterator[Callable[[Header], ExperienceBatch]]:
    """``transitions`` in order, in messages of at most ``batch_size`` tuples made under ``formulation``, each still
    to be given its header.

    The header comes last because its seq is the sender's to assign, one message at a time: the actor's outbox
    calls each with the next seq of its stream when it has room (``Outbox.add``); a benchmark calls them with the
    seqs it counts. Each part is a view of ``transitions`` (no copy: an actor's outbox holds the parts until they are
    acknowledged, and a copy would hold every tuple twice meanwhile).
    """
    for start in range(0, len(transitions), batch_size):
        part = transitions.take(slice(start, min(start + batch_size, len(transitions))))
        yield partial(experience_message, transitions=part, formulation=formulation)


def transitions_from_batch(msg: ExperienceBatch) -> Transitions:
    """The tuples of one experience message (arrays decoded from the wire are read-only views)."""
    return Transitions(
        robot=np.asarray(msg.robot),
        state=np.asarray(msg.state),
        action=np.asarray(msg.action),
        reward=np.asarray(msg.reward),
        next_state=np.asarray(msg.next_state),
        done=np.asarray(msg.done),
    )


def increment_message(
    header: Header, *, robot: int, change: np.ndarray, visits: np.ndarray, offsets: np.ndarray
) -> QTableIncrement:
    """The change (Σ P_a,) of one robot's table since the previous increment, with the visits behind it, over the
    discretization of ``header.policy_version``."""
    return QTableIncrement(
        actor_id=header.actor_id,
        incarnation=header.incarnation,
        seq=header.seq,
        policy_version=header.policy_version,
        robot=int(robot),
        q=np.asarray(change, np.float32),
        visits=_u32(np.asarray(visits)),
        offsets=np.asarray(offsets, np.int64),
    )


def increment_arrays(msg: QTableIncrement) -> tuple[int, np.ndarray, np.ndarray]:
    """(robot, change (Σ P_a,) float64, visits (Σ P_a,) float64) of an increment, ready for ``merge_increments``."""
    return int(msg.robot), np.array(msg.q, np.float64), np.asarray(msg.visits, np.float64)


def status_counters(figures: Any) -> dict[str, float]:
    """A process's typed figures (a dataclass of numbers) as a ``Status`` message's counters, field by field; a
    figure that is None (not measured yet) is left out, so a reader keeps its default."""
    values = {f.name: getattr(figures, f.name) for f in dataclasses.fields(figures)}
    return {name: float(v) for name, v in values.items() if v is not None}


def figures_from_counters(cls: type[F], counters: Mapping[str, float]) -> F:
    """The typed figures of a ``Status`` message; unknown names are ignored and missing ones keep their defaults
    (the sender may be a newer or older version). Fields annotated ``int`` come back as ints."""
    known = {f.name: f.type for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    values = {
        name: int(v) if known[name] in ("int", int) else float(v) for name, v in counters.items() if name in known
    }
    return cls(**values)
