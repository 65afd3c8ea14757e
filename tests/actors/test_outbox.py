"""The actor's outbox, policy client and increment tracker, each alone on the in-memory transport."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from actors.increments import IncrementTracker
from actors.outbox import Outbox
from actors.policy_client import PolicyClient
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.wire import policy_update
from protocol import Ack, Header, InMemoryBus, InMemoryTransport, Reject, Status
from sim.formulation import Formulation


def stamped(header: Header) -> Status:
    """A small message carrying the header the outbox gave it."""
    return Status(
        sender=header.actor_id,
        role="actor",
        wall_time=0.0,
        counters={"seq": float(header.seq), "policy_version": float(header.policy_version)},
    )


def never() -> bool:
    return False


def wait_until(predicate: Callable[[], bool], timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


def test_the_outbox_numbers_what_it_sends_and_a_full_one_waits_for_a_cumulative_ack() -> None:
    bus = InMemoryBus()
    received: list[float] = []
    with InMemoryTransport(bus) as actor, InMemoryTransport(bus) as learner:
        key = actor.keys.status("a0")
        learner.subscribe(key, Status, lambda m: received.append(m.counters["seq"]))
        outbox = Outbox(actor, "a0", incarnation=7, limit=3, resend_after=60.0, probe_key=key, stopping=never)
        sent = [outbox.add(key, stamped, policy_version=2) for _ in range(3)]
        assert [m.counters["seq"] for m in sent if m is not None] == [0.0, 1.0, 2.0] == received
        assert {m.counters["policy_version"] for m in sent if m is not None} == {2.0}
        outbox.on_ack(Ack(actor_id="a0", incarnation=6, seq=2))  # another incarnation's ack changes nothing
        assert len(outbox) == 3 and outbox.acked == -1
        # Full: the next add waits (sending nothing) until an ack makes room, then goes out under the next seq.
        added: list[Status | None] = []
        waiter = threading.Thread(target=lambda: added.append(outbox.add(key, stamped, policy_version=3)))
        waiter.start()
        assert wait_until(lambda: outbox.waits >= 1)
        assert received == [0.0, 1.0, 2.0] and not added
        outbox.on_ack(Ack(actor_id="a0", incarnation=7, seq=1))
        waiter.join(10.0)
        assert received == [0.0, 1.0, 2.0, 3.0] and added[0] is not None and added[0].counters["seq"] == 3.0
        assert len(outbox) == 2 and outbox.acked == 1


def test_stopping_with_a_full_outbox_sends_nothing_and_uses_no_seq() -> None:
    stop = threading.Event()
    received: list[float] = []
    with InMemoryTransport(InMemoryBus()) as actor:
        key = actor.keys.status("a0")
        actor.subscribe(key, Status, lambda m: received.append(m.counters["seq"]))
        outbox = Outbox(actor, "a0", incarnation=1, limit=1, resend_after=60.0, probe_key=key, stopping=stop.is_set)
        outbox.add(key, stamped, policy_version=0)
        stop.set()
        assert outbox.add(key, stamped, policy_version=0) is None and received == [0.0]
        stop.clear()
        outbox.on_ack(Ack(actor_id="a0", incarnation=1, seq=0))
        outbox.add(key, stamped, policy_version=0)
        assert received == [0.0, 1.0]  # no gap: the refused add used no seq


def test_an_invalid_message_is_dropped_before_the_wire_and_its_seq_goes_to_the_next() -> None:
    def invalid(header: Header) -> Status:
        return Status(sender=header.actor_id, role="actor", wall_time=float("nan"), counters={})

    received: list[float] = []
    with InMemoryTransport(InMemoryBus()) as actor:
        key = actor.keys.status("a0")
        actor.subscribe(key, Status, lambda m: received.append(m.counters["seq"]))
        outbox = Outbox(actor, "a0", incarnation=1, limit=4, resend_after=60.0, probe_key=key, stopping=never)
        assert outbox.add(key, invalid, policy_version=0) is None
        outbox.add(key, stamped, policy_version=0)
        assert received == [0.0] and outbox.invalid == 1 and len(outbox) == 1


def test_an_overdue_message_is_sent_again_before_the_next_one() -> None:
    received: list[float] = []
    with InMemoryTransport(InMemoryBus()) as actor:
        key = actor.keys.status("a0")
        actor.subscribe(key, Status, lambda m: received.append(m.counters["seq"]))
        # resend_after 0: every unacknowledged message is overdue by the time the next one is added.
        outbox = Outbox(actor, "a0", incarnation=1, limit=4, resend_after=0.0, probe_key=key, stopping=never)
        outbox.add(key, stamped, policy_version=0)
        outbox.add(key, stamped, policy_version=0)
        assert received == [0.0, 0.0, 1.0] and outbox.resent == 1


def test_overdue_messages_go_out_while_a_rejoined_learner_s_subscription_is_not_seen() -> None:
    # After a partition a session's view of the learner's subscription can stay stale. The join's "everything
    # again" waits for it, but overdue re-sends must not: a full outbox waiting on both deadlocked the actor.
    received: list[float] = []
    with InMemoryTransport(InMemoryBus()) as actor:
        key = actor.keys.status("a0")
        actor.subscribe(key, Status, lambda m: received.append(m.counters["seq"]))
        stale = actor.keys.status("nobody")  # a probe key no subscription ever matches
        outbox = Outbox(actor, "a0", incarnation=1, limit=2, resend_after=0.05, probe_key=stale, stopping=never)
        outbox.add(key, stamped, policy_version=0)
        outbox.add(key, stamped, policy_version=0)
        outbox.on_learner_join("alive/learner/l0")
        added: list[Status | None] = []
        worker = threading.Thread(target=lambda: added.append(outbox.add(key, stamped, policy_version=0)))
        worker.start()
        # The full outbox keeps re-sending its overdue messages; an ack of them makes room for the third.
        assert wait_until(lambda: received.count(0.0) >= 3 and received.count(1.0) >= 3)
        outbox.on_ack(Ack(actor_id="a0", incarnation=1, seq=1))
        worker.join(timeout=10.0)
        assert added and added[0] is not None and added[0].counters["seq"] == 2.0


def test_a_rejoining_learner_gets_the_whole_outbox_again_and_flush_ends_on_the_last_ack() -> None:
    bus = InMemoryBus()
    received: list[float] = []
    with InMemoryTransport(bus) as actor, InMemoryTransport(bus) as learner:
        key = actor.keys.status("a0")
        outbox = Outbox(actor, "a0", incarnation=1, limit=10, resend_after=60.0, probe_key=key, stopping=never)
        for _ in range(2):
            outbox.add(key, stamped, policy_version=0)  # nobody listens yet: both are lost

        def learner_receives(msg: Status) -> None:
            received.append(msg.counters["seq"])
            outbox.on_ack(Ack(actor_id="a0", incarnation=1, seq=int(msg.counters["seq"])))

        learner.subscribe(key, Status, learner_receives)
        outbox.on_learner_join("alive/learner/l0")
        # flush re-sends everything once the learner's subscription is matched, and returns on the last ack.
        assert outbox.flush(timeout=10.0) == 0
        assert received == [0.0, 1.0] and outbox.resent == 2 and outbox.acked == 1


LOCAL = Formulation.of("local2d", "observed", "compass")
"""The formulation of the one-cell policies below (their prototypes are 2-D)."""


def one_cell_policy(version: int, q: float) -> Policy:
    disc = Discretization.from_per_action([np.zeros((1, 2), np.float32)] * 8)
    return Policy(
        formulation=LOCAL,
        discretization=disc,
        tables=np.full((3, disc.size), q, np.float32),
        robot_table=np.arange(3),
        version=version,
    )


def test_policy_client_keeps_the_newest_and_the_learning_not_handed_in() -> None:
    tracker = IncrementTracker(robots=(0, 1))
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
    # The same discretization is kept as one object, with the search indexes it built; a new one replaces it.
    assert adopted.discretization is agent.discretization
    refit = one_cell_policy(4, 0.0)
    refit = dataclasses.replace(refit, discretization=dataclasses.replace(refit.discretization, labels=np.ones(8)))
    client.offer(policy_update(refit, "cmommt-v1"))
    after_refit = client.take()
    assert after_refit is not None and client.adopt(after_refit, adopted).discretization is not agent.discretization


def test_policy_client_refuses_a_broadcast_over_another_formulation_and_counts_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    def client(formulation: Formulation) -> PolicyClient:
        return PolicyClient(3, Phase2Config(), IncrementTracker(robots=(0,)), formulation)

    local = one_cell_policy(2, 0.0)
    other_reward = client(LOCAL)
    difference, eq2 = LOCAL.replace(reward="difference"), LOCAL.replace(reward="eq2")
    other_reward.offer(policy_update(dataclasses.replace(local, formulation=difference), "cmommt-v1"))
    other_reward.offer(policy_update(dataclasses.replace(local, version=3, formulation=eq2), "cmommt-v1"))
    other_state = client(LOCAL.replace(featurizer="collab6d"))
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
        "policy version 2 is refused: reward_function difference, expected observed (is the learner started with "
        "the same --formulation?)",
        "policy version 2 is refused: featurizer local2d, expected collab6d (is the learner started with the same "
        "--formulation?)",
        "policy version 2 is refused: its prototypes have 6 dimensions, local2d has 2 (is the learner started with "
        "the same --formulation?)",
    ]


def test_a_rejected_message_leaves_the_outbox_and_the_rest_flows_on() -> None:
    received: list[float] = []
    with InMemoryTransport(InMemoryBus()) as actor:
        key = actor.keys.status("a0")
        actor.subscribe(key, Status, lambda m: received.append(m.counters["seq"]))
        outbox = Outbox(actor, "a0", incarnation=3, limit=2, resend_after=60.0, probe_key=key, stopping=never)
        for _ in range(2):
            outbox.add(key, stamped, policy_version=0)
        outbox.on_reject(Reject(actor_id="a0", incarnation=2, seq=0, reason="another incarnation"))
        assert len(outbox) == 2
        outbox.on_reject(Reject(actor_id="a0", incarnation=3, seq=0, reason="InvalidValues: reward"))
        assert len(outbox) == 1 and outbox.rejected == 1
        outbox.add(key, stamped, policy_version=0)  # room again: the rejected message no longer holds a place
        outbox.on_ack(Ack(actor_id="a0", incarnation=3, seq=2))
        assert received == [0.0, 1.0, 2.0] and len(outbox) == 0 and outbox.resent == 0


def test_an_actor_sends_a_trial_in_batches_and_drops_an_invalid_one_without_using_a_seq() -> None:
    from actors.actor import RobotActor
    from actors.config import ActorConfig
    from algorithm.transitions import Transitions
    from protocol import ExperienceBatch

    reward = np.arange(5, dtype=np.float32)
    reward[2] = np.nan  # in the second batch of two
    tuples = Transitions(
        robot=np.zeros(5, np.int16),
        state=np.zeros((5, 6), np.float32),
        action=np.zeros(5, np.uint8),
        reward=reward,
        next_state=np.zeros((5, 6), np.float32),
        done=np.zeros(5, bool),
    )
    bus = InMemoryBus()
    seen: list[ExperienceBatch] = []
    with InMemoryTransport(bus) as transport, InMemoryTransport(bus) as learner:
        learner.subscribe(learner.keys.experience(), ExperienceBatch, seen.append)
        actor = RobotActor(transport, ActorConfig(actor_id="a0", arenas=1, batch_size=2))
        actor._send_experience(tuples)
    status = actor.status()
    # Tuples 0-1 and 4 went out as seqs 0 and 1: no gap for the learner where the invalid batch was dropped.
    assert [(m.seq, m.reward.tolist()) for m in seen] == [(0, [0.0, 1.0]), (1, [4.0])]
    assert {(m.actor_id, m.incarnation, m.policy_version) for m in seen} == {("a0", actor.incarnation, 0)}
    assert status.invalid == 1 and status.tuples_sent == 3 and status.batches_sent == 2 and status.outbox == 2


def test_a_paced_actor_sends_no_more_than_its_rate_allows() -> None:
    from actors.actor import RobotActor
    from actors.config import ActorConfig

    rate = 500.0
    config = ActorConfig(actor_id="a0", arenas=1, batch_size=4096, outbox_limit=100_000, flush_timeout=0, duration=1.5)
    with InMemoryTransport() as transport:
        paced = RobotActor(transport, dataclasses.replace(config, max_tuples_per_s=rate))
        began = time.monotonic()
        status = paced.run(threading.Event())
        elapsed = time.monotonic() - began
    with InMemoryTransport() as transport:
        free = RobotActor(transport, config).run(threading.Event())
    per_trial = status.tuples_sent / status.trials
    # The rest comes after each trial, so the sent tuples stay within the rate plus the trial in hand.
    assert status.trials >= 2 and status.tuples_sent <= rate * elapsed + per_trial
    assert free.tuples_sent > 3 * status.tuples_sent  # unpaced, the same 1.5 s sends many times more


def test_an_actor_runs_learning_trials_of_the_length_it_is_given() -> None:
    from actors.actor import RobotActor
    from actors.config import ActorConfig

    config = ActorConfig(actor_id="a0", arenas=1, batch_size=4096, outbox_limit=100_000, flush_timeout=0)
    with InMemoryTransport() as transport:
        default = RobotActor(transport, config)
        longer = RobotActor(transport, dataclasses.replace(config, learning_steps=250))
    # Phase 0: random exploration, every robot of the one arena deciding once per held action to the trial's end.
    assert default.scenario.learning_steps == 100 and longer.scenario.learning_steps == 250
    for actor, steps in ((default, 100), (longer, 250)):
        batch = actor.slice.run_trial()
        assert len(batch) == actor.scenario.n_robots * steps // actor.scenario.action_steps
    with pytest.raises(ValueError, match="learning_steps"):
        ActorConfig(learning_steps=0)
