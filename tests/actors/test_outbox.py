"""The actor's outbox, policy client and increment tracker, each alone on the in-memory transport."""

from __future__ import annotations

import threading

import numpy as np

from actors.increments import IncrementTracker
from actors.outbox import Outbox
from actors.policy_client import PolicyClient
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.wire import policy_update
from protocol import Ack, InMemoryBus, InMemoryTransport, Status


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


def one_cell_policy(version: int, q: float) -> Policy:
    disc = Discretization.from_per_action([np.zeros((1, 2), np.float32)] * 8)
    return Policy(
        featurizer="local2d",
        discretization=disc,
        tables=np.full((3, disc.size), q, np.float32),
        robot_table=np.arange(3),
        version=version,
    )


def test_policy_client_keeps_the_newest_and_the_learning_not_handed_in() -> None:
    tracker = IncrementTracker(learn=(0, 1))
    client = PolicyClient(n_robots=3, phase2=Phase2Config(), tracker=tracker, featurizer="local2d")
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


def test_policy_client_refuses_a_broadcast_over_another_state_and_counts_it() -> None:
    client = PolicyClient(
        n_robots=3, phase2=Phase2Config(), tracker=IncrementTracker(learn=(0,)), featurizer="collab6d"
    )
    client.offer(policy_update(one_cell_policy(2, 0.0), "cmommt-v1"))  # a local2d policy: 2-D prototypes
    client.offer(policy_update(one_cell_policy(3, 0.0), "cmommt-v1"))
    assert client.take() is None and client.refused == 2 and client.version == 0


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
