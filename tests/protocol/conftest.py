"""Shared samples and hypothesis strategies of the protocol tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from protocol import (
    N_ACTIONS,
    Ack,
    ActorView,
    ExperienceBatch,
    Message,
    PolicyUpdate,
    QTableIncrement,
    Reject,
    Status,
)

OFFSETS = np.arange(N_ACTIONS + 1, dtype=np.int64)  # one prototype per action


def sample_batch() -> ExperienceBatch:
    return ExperienceBatch(
        actor_id="actor-0",
        incarnation=0x0123456789ABCDEF,
        seq=7,
        policy_version=3,
        featurizer="local2d",
        reward_function="observed",
        action_set="compass",
        robot=np.array([0, 5], np.int16),
        state=np.array([[0.5, -1.0], [2.0, 0.25]], np.float32),
        action=np.array([1, 7], np.uint8),
        reward=np.array([1.0, -0.5], np.float32),
        next_state=np.array([[0.75, -1.0], [2.0, 0.0]], np.float32),
        done=np.array([False, True]),
    )


def sample_policy(version: int = 3) -> PolicyUpdate:
    return PolicyUpdate(
        version=version,
        scenario="cmommt-v1",
        featurizer="local2d",
        reward_function="observed",
        action_set="compass",
        action_steps=5,
        prototypes=np.arange(2 * N_ACTIONS, dtype=np.float32).reshape(N_ACTIONS, 2) * np.float32(0.25),
        labels=np.linspace(0.0, 1.0, N_ACTIONS, dtype=np.float32),
        offsets=OFFSETS,
        robots=np.array([0, 5], np.int16),
        q_tables=np.ones((2, N_ACTIONS), np.float32),
        visits=np.full((2, N_ACTIONS), 10, np.uint32),
        scale=np.array([1.0, 0.5], np.float32),
    )


def golden_samples() -> dict[str, Message]:
    """One small, fixed message per type; their encodings are pinned in tests/protocol/golden/."""
    return {
        "experience": sample_batch(),
        "qinc": QTableIncrement(
            actor_id="actor-0",
            incarnation=0x0123456789ABCDEF,
            seq=8,
            policy_version=3,
            robot=5,
            q=np.linspace(-1.0, 1.0, N_ACTIONS, dtype=np.float32),
            visits=np.arange(N_ACTIONS, dtype=np.uint32),
            offsets=OFFSETS,
        ),
        "policy": sample_policy(),
        "ack": Ack(actor_id="actor-0", incarnation=0x0123456789ABCDEF, seq=8),
        "reject": Reject(actor_id="actor-0", incarnation=0x0123456789ABCDEF, seq=9, reason="InvalidValues: reward"),
        "status": Status(
            sender="learner-0", role="learner", wall_time=1700000000.25, counters={"tuples": 1024.0, "lag": 0.5}
        ),
        "view": sample_view(),
    }


def sample_view() -> ActorView:
    """Two arena frames of 3 robots and 2 targets, and the trial's figures."""
    return ActorView(
        actor_id="actor-0",
        sim_step=200,
        train_time=12.5,
        wall_time=1700000000.25,
        counters={"coverage": 61.25, "policy_version": 4.0, "rss_mb": 281.5},
        frame_step=np.array([101, 102], np.uint64),
        frame_time=np.array([12.0, 12.25], np.float64),
        robot_pos=np.arange(12, dtype=np.float32).reshape(2, 3, 2),
        target_pos=-np.arange(8, dtype=np.float32).reshape(2, 2, 2),
        sensing_range=150.0,
        arena_radius=1000.0,
    )


ids = st.from_regex(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}", fullmatch=True)
u64 = st.integers(0, 2**64 - 1)
f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
robot_ids = st.integers(0, 2**15 - 1)


def _offsets(draw: st.DrawFn, total: int) -> np.ndarray:
    cuts = sorted(draw(st.lists(st.integers(0, total), min_size=N_ACTIONS - 1, max_size=N_ACTIONS - 1)))
    return np.array([0, *cuts, total], np.int64)


@st.composite
def experience_batches(draw: st.DrawFn) -> ExperienceBatch:
    n, d = draw(st.integers(0, 12)), draw(st.sampled_from([2, 6]))
    return ExperienceBatch(
        actor_id=draw(ids),
        incarnation=draw(u64),
        seq=draw(u64),
        policy_version=draw(u64),
        featurizer=draw(ids),
        reward_function=draw(ids),
        action_set=draw(ids),
        robot=draw(hnp.arrays(np.int16, n, elements=robot_ids)),
        state=draw(hnp.arrays(np.float32, (n, d), elements=f32)),
        action=draw(hnp.arrays(np.uint8, n, elements=st.integers(0, N_ACTIONS - 1))),
        reward=draw(hnp.arrays(np.float32, n, elements=f32)),
        next_state=draw(hnp.arrays(np.float32, (n, d), elements=f32)),
        done=draw(hnp.arrays(np.bool_, n)),
    )


@st.composite
def q_increments(draw: st.DrawFn) -> QTableIncrement:
    p = draw(st.integers(0, 20))
    return QTableIncrement(
        actor_id=draw(ids),
        incarnation=draw(u64),
        seq=draw(u64),
        policy_version=draw(u64),
        robot=draw(robot_ids),
        q=draw(hnp.arrays(np.float32, p, elements=f32)),
        visits=draw(hnp.arrays(np.uint32, p)),
        offsets=_offsets(draw, p),
    )


@st.composite
def policy_updates(draw: st.DrawFn) -> PolicyUpdate:
    p, d = draw(st.integers(0, 20)), draw(st.integers(1, 8))
    robots = np.array(draw(st.lists(robot_ids, max_size=4, unique=True)), np.int16)
    return PolicyUpdate(
        version=draw(st.integers(1, 2**64 - 1)),
        scenario=draw(st.text(st.characters(categories=["L", "N", "P"]), min_size=1, max_size=64)),
        featurizer=draw(ids),
        reward_function=draw(ids),
        action_set=draw(ids),
        action_steps=draw(st.integers(1, 100)),
        prototypes=draw(hnp.arrays(np.float32, (p, d), elements=f32)),
        labels=draw(hnp.arrays(np.float32, p, elements=f32)),
        offsets=_offsets(draw, p),
        robots=robots,
        q_tables=draw(hnp.arrays(np.float32, (robots.size, p), elements=f32)),
        visits=draw(hnp.arrays(np.uint32, (robots.size, p))),
        scale=np.array(draw(st.lists(st.floats(0.125, 1024.0, width=32), min_size=d, max_size=d)), np.float32),
    )


acks = st.builds(Ack, actor_id=ids, incarnation=u64, seq=u64)
rejects = st.builds(
    Reject,
    actor_id=ids,
    incarnation=u64,
    seq=u64,
    reason=st.text(st.characters(codec="ascii", categories=["L", "N", "P", "Zs"]), min_size=1, max_size=64),
)
statuses = st.builds(
    Status,
    sender=ids,
    role=st.sampled_from(["learner", "actor", "evaluator"]),
    wall_time=st.floats(allow_nan=False, allow_infinity=False),
    counters=st.dictionaries(
        st.text(min_size=1, max_size=64), st.floats(allow_nan=False, allow_infinity=False), max_size=64
    ),
)
messages = st.one_of(experience_batches(), q_increments(), policy_updates(), acks, rejects, statuses)
