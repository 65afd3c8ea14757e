"""The actor's outbox, policy client and increment tracker, each alone on the in-memory transport."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from actors.increments import IncrementTracker
from actors.outbox import Outbox
from actors.policy_client import PolicyClient
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.wire import policy_update
from protocol import Ack, InMemoryBus, InMemoryTransport, Status
from sim.features import Formulation


def status(seq: int) -> Status:
    return Status(sender="a0", role="actor", wall_time=0.0, counters={"seq": float(seq)})


def test_cumulative_acks_drain_the_outbox_and_a_full_one_waits() -> None:
    bus = InMemoryBus()
    received: list[float] = []
    with InMemoryTransport(bus) as actor, InMemoryTransport(bus) as learner:
        learner.subscribe(learner.keys.status("a0"), Status, lambda m: received.append(m.counters["seq"]))
        outbox = Outbox(actor, incarnation=7, limit=3, resend_after=60.0, probe_key=actor.keys.status("a0"))
        first = outbox.reserve(3)
        for seq in range(first, first + 3):
            outbox.send(actor.keys.status("a0"), status(seq), seq)
        assert len(outbox) == 3 and received == [0.0, 1.0, 2.0]
        outbox.on_ack(Ack(actor_id="a0", incarnation=6, seq=2))  # another incarnation's ack changes nothing
        assert len(outbox) == 3 and outbox.acked == -1
        # Full: wait_for_room blocks until an ack makes room.
        done = threading.Event()
        waiter = threading.Thread(target=lambda: (outbox.wait_for_room(threading.Event()), done.set()))
        waiter.start()
        assert not done.wait(0.3)
        outbox.on_ack(Ack(actor_id="a0", incarnation=7, seq=1))
        assert done.wait(10.0)
        waiter.join()
        assert len(outbox) == 1 and outbox.acked == 1 and outbox.waits >= 1
        assert outbox.reserve() == 3  # sequence numbers go on after the reserved block


def test_a_rejoining_learner_gets_the_whole_outbox_again_and_flush_ends_on_the_last_ack() -> None:
    bus = InMemoryBus()
    received: list[float] = []
    with InMemoryTransport(bus) as actor, InMemoryTransport(bus) as learner:
        outbox = Outbox(actor, incarnation=1, limit=10, resend_after=60.0, probe_key=actor.keys.status("a0"))
        for seq in range(outbox.reserve(2), 2):
            outbox.send(actor.keys.status("a0"), status(seq), seq)  # nobody listens yet: both are lost
        learner.subscribe(learner.keys.status("a0"), Status, lambda m: received.append(m.counters["seq"]))
        outbox.on_learner_join("alive/learner/l0")
        outbox.wait_for_room(threading.Event())  # re-sends everything once the learner's subscription is matched
        assert received == [0.0, 1.0] and outbox.resent == 2
        outbox.on_ack(Ack(actor_id="a0", incarnation=1, seq=1))
        assert outbox.flush(timeout=5.0) == 0


LOCAL = Formulation("local2d", "observed")
"""The formulation of the one-cell policies below (their prototypes are 2-D)."""


def one_cell_policy(version: int, q: float) -> Policy:
    disc = Discretization.from_per_action([np.zeros((1, 2), np.float32)] * 8)
    return Policy(
        featurizer="local2d",
        discretization=disc,
        tables=np.full((3, disc.size), q, np.float32),
        robot_table=np.arange(3),
        version=version,
        reward="observed",
    )


def test_policy_client_keeps_the_newest_and_the_learning_not_handed_in() -> None:
    tracker = IncrementTracker(learn=(0, 1))
    client = PolicyClient(n_robots=3, phase2=Phase2Config(), tracker=tracker, formulation=LOCAL)
    client.offer(policy_update(one_cell_policy(2, 0.0), "cmommt-v1"))
    client.offer(policy_update(one_cell_policy(1, 9.0), "cmommt-v1"))  # older: ignored
    update = client.take()
    assert update is not None and update.version == 2 and client.take() is None
    agent = client.adopt(update, None)
    assert client.version == 2 and client.adopted == 1
    # Robot 0 learns +1 in cell 0 and hands it in; then it learns +0.5 more that is not handed in yet.
    agent.tables[0, 0] += 1.0
    agent.visits[0, 0] += 1
    handed = tracker.take(agent)
    assert [(r, c[0], v[0]) for r, c, v in handed] == [(0, 1.0, 1)]
    agent.tables[0, 0] += 0.5
    agent.visits[0, 0] += 1
    # A broadcast over the same cells that already merged the +1: the +0.5 stays on top of it.
    client.offer(policy_update(one_cell_policy(3, 1.0), "cmommt-v1"))
    newer = client.take()
    assert newer is not None
    adopted: TabularAgent = client.adopt(newer, agent)
    assert adopted.tables[0, 0] == 1.5 and adopted.tables[2, 0] == 1.0  # robot 2 is not learned here
    assert [(r, c[0], v[0]) for r, c, v in tracker.take(adopted)] == [(0, 0.5, 1)]


def test_policy_client_refuses_a_broadcast_over_another_formulation_and_counts_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    def client(formulation: Formulation) -> PolicyClient:
        return PolicyClient(3, Phase2Config(), IncrementTracker(learn=(0,)), formulation)

    local = one_cell_policy(2, 0.0)
    other_reward = client(LOCAL)
    other_reward.offer(policy_update(dataclasses.replace(local, reward="difference"), "cmommt-v1"))
    other_reward.offer(policy_update(dataclasses.replace(local, version=3, reward="eq2"), "cmommt-v1"))
    other_state = client(Formulation("collab6d", "observed"))
    other_state.offer(policy_update(local, "cmommt-v1"))
    # The wire checks names for their syntax only: a broadcast naming local2d over 6-D prototypes is refused here.
    six = policy_update(local, "cmommt-v1")
    wrong_dim = client(LOCAL)
    wrong_dim.offer(dataclasses.replace(six, prototypes=np.zeros((8, 6), np.float32), scale=np.ones(6, np.float32)))
    assert [(c.take(), c.refused, c.version) for c in (other_reward, other_state, wrong_dim)] == [
        (None, 2, 0),
        (None, 1, 0),
        (None, 1, 0),
    ]
    refusals = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert refusals == [  # logged once per client, counted every time
        "policy version 2 is refused: it is over the local2d/difference/compass formulation, this actor's is "
        "local2d/observed/compass (is the learner started with the same --formulation?)",
        "policy version 2 is refused: it is over the local2d/observed/compass formulation, this actor's is "
        "collab6d/observed/compass (is the learner started with the same --formulation?)",
        "policy version 2 is refused: its prototypes have 6 dimensions, local2d has 2 (is the learner started with "
        "the same --formulation?)",
    ]


def test_a_rejected_message_leaves_the_outbox_and_the_rest_flows_on() -> None:
    from protocol import Reject

    with InMemoryTransport(InMemoryBus()) as actor:
        outbox = Outbox(actor, incarnation=3, limit=2, resend_after=60.0, probe_key=actor.keys.status("a0"))
        for seq in range(outbox.reserve(2), 2):
            outbox.send(actor.keys.status("a0"), status(seq), seq)
        outbox.on_reject(Reject(actor_id="a0", incarnation=2, seq=0, reason="another incarnation"))
        assert len(outbox) == 2
        outbox.on_reject(Reject(actor_id="a0", incarnation=3, seq=0, reason="InvalidValues: reward"))
        assert len(outbox) == 1 and outbox.rejected == 1
        outbox.wait_for_room(threading.Event())  # room again: the rejected message no longer holds a place
        outbox.on_ack(Ack(actor_id="a0", incarnation=3, seq=1))
        assert len(outbox) == 0


def test_an_actor_drops_its_own_invalid_message_before_the_wire_without_using_a_seq() -> None:
    from actors.actor import RobotActor
    from actors.config import ActorConfig
    from algorithm.transitions import Transitions
    from protocol import ExperienceBatch

    def tuples(reward: float) -> Transitions:
        return Transitions(
            robot=np.zeros(2, np.int16),
            state=np.zeros((2, 6), np.float32),
            action=np.zeros(2, np.uint8),
            reward=np.full(2, reward, np.float32),
            next_state=np.zeros((2, 6), np.float32),
            done=np.zeros(2, bool),
        )

    bus = InMemoryBus()
    seen: list[int] = []
    with InMemoryTransport(bus) as transport, InMemoryTransport(bus) as learner:
        learner.subscribe(learner.keys.experience(), ExperienceBatch, lambda m: seen.append(m.seq))
        actor = RobotActor(transport, ActorConfig(actor_id="a0", arenas=1))
        actor._send_experience(tuples(np.nan))
        actor._send_experience(tuples(0.0))
    status = actor.status()
    assert seen == [0]  # the valid batch took seq 0: no gap for the learner
    assert status.invalid == 1 and status.tuples_sent == 2 and status.batches_sent == 1
