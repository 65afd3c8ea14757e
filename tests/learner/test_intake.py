"""The intake's rejection accounting: one count per arrival, the Reject sent once, the counts kept by checkpoints."""

from __future__ import annotations

import msgpack
import numpy as np

from learner.intake import ExperienceIntake
from protocol import ExperienceBatch, InMemoryBus, InMemoryTransport, InvalidValues, Reject, encode
from sim.formulation import FORMULATIONS

PAPER = FORMULATIONS["paper"]  # collab6d: d = 6


def batch(seq: int, dim: int = 6, actor: str = "a") -> ExperienceBatch:
    n = 4
    return ExperienceBatch(
        actor_id=actor,
        incarnation=7,
        seq=seq,
        policy_version=0,
        featurizer=PAPER.featurizer.name,
        reward_function=PAPER.reward.name,
        action_set=PAPER.actions.name,
        robot=np.zeros(n, np.int16),
        state=np.zeros((n, dim), np.float32),
        action=np.zeros(n, np.uint8),
        reward=np.zeros(n, np.float32),
        next_state=np.zeros((n, dim), np.float32),
        done=np.zeros(n, bool),
    )


def poisoned(seq: int, actor: str = "a") -> bytes:
    """A batch with a NaN reward, as a client written from docs/reference/protocol.md would send it: valid msgpack."""
    envelope = msgpack.unpackb(encode(batch(seq)), raw=False)
    envelope[2]["reward"] = ["float32", [4], np.array([0, np.nan, 0, 0], np.float32).tobytes()]
    envelope[2]["actor_id"] = actor
    return msgpack.packb(envelope, use_bin_type=True)


def test_a_re_sent_refused_message_is_one_rejection_and_one_duplicate() -> None:
    rejects: list[Reject] = []
    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(t.keys.reject(), Reject, rejects.append)
        intake = ExperienceIntake(100, PAPER, t)
        key = t.keys.experience("a")
        intake.on_rejected(key, poisoned(0), InvalidValues("reward: NaN"))
        intake.on_rejected(key, poisoned(0), InvalidValues("reward: NaN"))  # the outbox re-sent it
        intake.on_experience(batch(1, dim=2))
        intake.on_experience(batch(1, dim=2))
        intake.on_experience(batch(2))
        intake.on_experience(batch(2))
    figures = intake.figures()
    assert [(r.seq, r.reason) for r in rejects] == [
        (0, "InvalidValues: reward: NaN"),
        (1, "state dimension 2, expected 6"),
    ]
    assert figures.rejected_by_type == {"InvalidValues": 1, "StateDimension": 1} and figures.refused == 2
    assert figures.duplicates == 3 and figures.accepted == 3 and figures.tuples_received == 4


def test_a_payload_that_cannot_be_tied_to_its_stream_is_counted_at_each_arrival() -> None:
    rejects: list[Reject] = []
    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(t.keys.reject(), Reject, rejects.append)
        intake = ExperienceIntake(100, PAPER, t)
        for _ in range(2):
            intake.on_rejected(t.keys.experience("a"), b"\x93\x01garbage", InvalidValues("garbage"))
            intake.on_rejected(t.keys.experience("a"), poisoned(0, actor="b"), InvalidValues("lie"))  # b's stream
    figures = intake.figures()
    assert figures.rejected_by_type == {"InvalidValues": 4} and figures.refused == 0
    assert figures.duplicates == 0 and rejects == []  # b never hears of a's lie: its seq 0 is still to come


def test_rejection_counts_survive_a_checkpoint() -> None:
    rejects: list[Reject] = []
    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(t.keys.reject(), Reject, rejects.append)
        intake = ExperienceIntake(100, PAPER, t)
        intake.on_rejected(t.keys.experience("a"), poisoned(0), InvalidValues("reward: NaN"))
        intake.on_experience(batch(1, dim=2))
        arrays, acks = intake.checkpoint_arrays()
        resumed = ExperienceIntake(100, PAPER, t)
        resumed.restore(arrays)
        resumed.on_rejected(t.keys.experience("a"), poisoned(0), InvalidValues("reward: NaN"))  # re-sent after resume
    figures = resumed.figures()
    assert acks == [("a", 7, 1)]  # the cumulative ack steps over both refused messages
    assert figures.rejected_by_type == {"InvalidValues": 1, "StateDimension": 1} and figures.refused == 2
    assert figures.duplicates == 1 and len(rejects) == 2
