"""The learner service and a robot actor in one process over the in-memory transport (serial mode)."""

from __future__ import annotations

import dataclasses
import itertools
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from actors.actor import ActorStatus, RobotActor
from actors.config import ActorConfig, parse_robots
from actors.wiring import connect as connect_actor
from algorithm.discretization import Discretization
from algorithm.phase1 import Phase1Config
from algorithm.policy import PolicyController
from algorithm.selection import TEST_SEED
from learner.config import LearnerConfig
from learner.policy_state import PolicyState
from learner.service import LearnerService
from learner.wiring import connect as connect_learner
from protocol import ExperienceBatch, InMemoryBus, InMemoryTransport, PolicyUpdate, QTableIncrement, Reject
from sim import HAND_MADE, evaluate
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS
from tests.fakes import run_until, run_with_actor

FAST = LearnerConfig(
    min_tuples=8000,
    phase1=Phase1Config(max_iterations=1, n_cycles=20, max_patterns=800),
    broadcast_interval=0.5,
    eval_interval=1000.0,
    eval_trials=2,
    eval_steps=100,
    checkpoint_interval=0.5,
    duration=120.0,
    margin_trials=3,
)


@pytest.mark.slow
def test_serial_learner_and_actor_exchange_experience_and_policies(tmp_path: Path) -> None:
    bus = InMemoryBus()
    versions: list[int] = []
    with InMemoryTransport(bus) as lt, InMemoryTransport(bus) as at, InMemoryTransport(bus) as watcher:
        watcher.subscribe(watcher.keys.policy(), PolicyUpdate, lambda u: versions.append(u.version))
        service = LearnerService(lt, FAST, tmp_path)
        handles = connect_learner(service, lt)
        actor = RobotActor(
            at, ActorConfig(actor_id="a0", arenas=16, learn=(0, 1, 2), batch_size=256, flush_timeout=0.5)
        )
        handles.enter_context(connect_actor(actor, at))
        stop = threading.Event()
        result: list[ActorStatus] = []
        thread = threading.Thread(target=lambda: result.append(actor.run(stop)))
        thread.start()
        # The wind-down (here a final evaluation made 3 s slower) is no training: the run clock stops with training.
        final, stopped_at = service.evaluator.final, []

        def slow_final(policy: Any, *args: Any) -> float:
            time.sleep(3.0)
            return final(policy, *args)

        def done() -> bool:
            if service.state.increments >= 3 and len(versions) >= 2:
                stopped_at.append(service.elapsed())
                return True
            return False

        service.evaluator.final = slow_final  # type: ignore[method-assign]
        report = run_until(service, done)
        stop.set()
        thread.join()
        handles.close()  # the ExitStack connect returned: every handle, in reverse order
    status = result[0]
    assert versions == sorted(set(versions)) and len(versions) >= 2  # strictly increasing broadcasts
    assert report.policy_version == versions[-1]
    assert report.tuples_by_actor["a0"] >= status.tuples_sent - status.outbox * 256
    assert report.gaps == 0 and report.duplicates == 0 and report.rejected == 0
    assert round(stopped_at[0], 2) <= report.seconds < stopped_at[0] + 1.5  # the report rounds to 0.01 s
    assert report.increments > 0 and status.policies_applied >= 1
    # Only the learned robots produced tuples, and their tables (the broadcast's rows) moved away from the phase-1
    # labels; the policy evaluated and saved holds every robot's own row (option 2).
    assert report.prototypes_per_action and (tmp_path / "checkpoint.npz").exists()
    policy, current = service.state.policy(), service.state.current
    assert policy is not None and current is not None and policy.tables.shape[0] == 10
    moved = np.abs(current.q_tables - policy.discretization.labels[None, :]).sum(axis=1)
    assert (moved[[0, 1, 2]] > 0).all() and (moved[3:] == 0).all()


DIM = FORMULATIONS[DEFAULT_FORMULATION].dim
"""State dimension of the default formulation, FAST's."""
PAPER = FORMULATIONS["paper"]


def one_cell_per_action(dim: int = 6) -> Discretization:
    return Discretization.from_per_action([np.zeros((1, dim), np.float32)] * 8)


def increment(
    actor: str, seq: int, q: list[float], visits: list[int], version: int = 1, robot: int = 2
) -> QTableIncrement:
    return QTableIncrement(
        actor_id=actor,
        incarnation=1,
        seq=seq,
        policy_version=version,
        robot=robot,
        q=np.array(q, np.float32),
        visits=np.array(visits, np.uint32),
        offsets=one_cell_per_action().offsets,
    )


def test_merge_adds_the_visit_weighted_mean_of_the_actors_changes(tmp_path: Path) -> None:
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, FAST, tmp_path)
        service.state.adopt(one_cell_per_action(dim=DIM))  # FAST's formulation: the default
        first = service.state.publish()  # version 1 over the labels (all 0)
        service.on_increment(increment("a", 0, [1, 0, 0, 0, 0, 0, 0, 0], [1, 0, 0, 0, 0, 0, 0, 0]))
        service.on_increment(increment("a", 1, [1, 2, 0, 0, 0, 0, 0, 0], [1, 2, 0, 0, 0, 0, 0, 0]))  # adds up
        service.on_increment(increment("b", 0, [4, 0, 0, 0, 0, 0, 0, 0], [6, 0, 0, 0, 0, 0, 0, 0]))
        service.on_increment(increment("b", 0, [9, 9, 9, 9, 9, 9, 9, 9], [9, 9, 9, 9, 9, 9, 9, 9]))  # duplicate seq
        update = service.state.publish()
    # Cell 0: actor a changed it by 2 over 2 visits, actor b by 4 over 6 visits -> (2*2 + 4*6) / 8 = 3.5.
    assert first.version == 1 and update.version == 2
    assert update.q_tables[2, 0] == pytest.approx(3.5)
    assert update.q_tables[2, 1] == pytest.approx(2.0)
    assert update.q_tables[2, 2:].sum() == 0 and update.q_tables[[0, 1, 3]].sum() == 0
    assert update.visits[2, 0] == 8 and service.intake.figures().duplicates == 1


def test_increments_over_an_old_discretization_are_dropped() -> None:
    state = PolicyState(n_robots=10, formulation=PAPER, scenario="cmommt-v1", action_steps=5, method="m")
    state.adopt(one_cell_per_action())
    state.publish()  # version 1 over the first discretization
    state.adopt(one_cell_per_action())  # a refit: version 1's cells mean something else now
    state.publish()
    assert not state.add_increment(increment("a", 0, [1.0] * 8, [1] * 8, version=1))
    assert state.add_increment(increment("a", 1, [1.0] * 8, [1] * 8, version=2))
    assert state.stale_increments == 1 and state.increments == 2
    update = state.publish()
    assert update.q_tables[2].tolist() == [1.0] * 8  # only the current discretization's increment was merged


def test_the_evaluated_policy_decides_every_act_every_steps_while_the_broadcast_keeps_the_actors_hold() -> None:
    kw: dict[str, Any] = {"n_robots": 10, "scenario": "cmommt-v1", "method": "m"}
    every_step = PAPER.replace(reward="difference", act_every=1)
    state = PolicyState(formulation=every_step, action_steps=5, **kw)
    state.adopt(one_cell_per_action())
    assert state.publish().action_steps == 5
    policy = state.policy()
    assert policy is not None and (policy.action_steps, policy.formulation) == (1, every_step)
    plain = PolicyState(formulation=PAPER, action_steps=5, **kw)
    plain.adopt(one_cell_per_action())
    assert plain.policy() is not None and plain.policy().action_steps == 5  # type: ignore[union-attr]


def test_a_team_policy_is_evaluated_on_the_merged_rows_while_each_robot_gets_its_own() -> None:
    state = PolicyState(n_robots=10, formulation=PAPER, scenario="cmommt-v1", action_steps=5, method="m", team=True)
    state.adopt(one_cell_per_action())
    state.publish()  # version 1: the increments are learned over it
    state.add_increment(increment("a", 0, [4.0] * 8, [1] * 8, robot=2))
    state.add_increment(increment("a", 1, [1.0] * 8, [3] * 8, robot=5))
    update = state.publish()
    assert update.q_tables.shape[0] == 10 and update.q_tables[2, 0] == pytest.approx(4.0)
    policy = state.policy()
    assert policy is not None and policy.tables.shape[0] == 1
    assert policy.tables[0, 0] == pytest.approx((4.0 + 3 * 1.0) / 4) and policy.robot_table.tolist() == [0] * 10


DEFAULT = FORMULATIONS[DEFAULT_FORMULATION]


def experience(seq: int, dim: int = DIM, reward_function: str = DEFAULT.reward.name, n: int = 3) -> ExperienceBatch:
    return ExperienceBatch(
        actor_id="a",
        incarnation=1,
        seq=seq,
        policy_version=0,
        featurizer=DEFAULT.featurizer.name,
        reward_function=reward_function,
        action_set=DEFAULT.actions.name,
        robot=np.zeros(n, np.int16),
        state=np.zeros((n, dim), np.float32),
        action=np.zeros(n, np.uint8),
        reward=np.zeros(n, np.float32),
        next_state=np.zeros((n, dim), np.float32),
        done=np.zeros(n, bool),
    )


def test_experience_of_another_formulation_or_dimension_is_rejected_and_counted(tmp_path: Path) -> None:
    rejects: list[tuple[int, str]] = []
    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(t.keys.reject("a"), Reject, lambda r: rejects.append((r.seq, r.reason)))
        service = LearnerService(t, FAST, tmp_path)  # the default formulation
        handles = connect_learner(service, t)
        good = experience(seq=0)
        t.publish(t.keys.experience("a"), good)
        t.publish(t.keys.experience("a"), experience(seq=1, dim=2))
        t.publish(t.keys.experience("a"), experience(seq=2, reward_function="eq2"))  # the paper's reward
        t.inject_raw(t.keys.experience("a"), b"\x93\x01garbage")
        t.publish(t.keys.experience("a"), good)  # a re-sent duplicate
        handles.close()  # the ExitStack connect returned: every handle, in reverse order
    figures = service.intake.figures()
    assert figures.tuples_received == 3 and figures.store_size == 3
    assert figures.rejected_by_type == {"StateDimension": 1, "Formulation": 1, "MalformedMessage": 1}
    assert figures.rejected == 3
    assert sum(t.stats.rejected.values()) == 1  # the transport saw only the garbage
    assert figures.duplicates == 1
    assert rejects == [
        (1, f"state dimension 2, expected {DIM}"),
        (2, f"reward_function eq2, expected {DEFAULT.reward.name}"),
    ]


def test_parse_robots() -> None:
    assert parse_robots("0-2,7, 5") == (0, 1, 2, 5, 7)
    for bad in ("", "3-1", "x"):
        with pytest.raises(ValueError):
            parse_robots(bad)


@pytest.mark.slow
def test_refits_warm_start_and_carry_q_values_over(tmp_path: Path) -> None:
    config = LearnerConfig(
        min_tuples=6000,
        refit_growth=2.0,
        phase1=Phase1Config(max_iterations=1, n_cycles=15, max_patterns=600),
        broadcast_interval=0.3,
        eval_interval=1000.0,
        eval_trials=1,
        eval_steps=50,
        checkpoint_interval=0.5,
        duration=120.0,
    )
    bus = InMemoryBus()
    prototypes_seen: list[int] = []
    with InMemoryTransport(bus) as lt, InMemoryTransport(bus) as at, InMemoryTransport(bus) as watcher:
        watcher.subscribe(watcher.keys.policy(), PolicyUpdate, lambda u: prototypes_seen.append(u.n_prototypes))
        service = LearnerService(lt, config, tmp_path)
        report = run_with_actor(service, lt, at, lambda: service.fitter.fits >= 2 and len(set(prototypes_seen)) >= 2)
    assert report.phase1_fits >= 2  # refitted as the data grew
    assert len(set(prototypes_seen)) >= 2  # broadcasts carried the new discretization
    policy = service.state.policy()
    assert policy is not None
    # Carried-over tables are not the new labels: learned values survived the change of cells.
    assert not np.allclose(policy.tables, policy.discretization.labels[None, :])


def test_a_checkpoint_holds_the_pending_increments_and_the_resume_goes_above_every_version(tmp_path: Path) -> None:
    recorded: list[int] = []
    state = PolicyState(10, PAPER, "cmommt-v1", 5, "m", on_version=recorded.append)
    state.adopt(one_cell_per_action())
    state.publish()
    assert state.add_increment(increment("a", 0, [2.0] + [0.0] * 7, [4] + [0] * 7))  # acked, not merged yet
    arrays, meta = state.to_arrays()
    state.publish()
    state.publish()  # versions 2 and 3 go out after the checkpoint; the mark knows them
    assert recorded == [1, 2, 3]
    resumed = PolicyState(10, PAPER, "cmommt-v1", 5, "m", on_version=recorded.append)
    resumed.restore(arrays, meta, published=max(recorded))
    current = resumed.current
    assert current is not None and current.version == 4 and recorded[-1] == 4
    assert resumed.add_increment(increment("b", 0, [1.0] * 8, [1] * 8, version=3))  # stamped after the checkpoint
    update = resumed.publish()
    # The pending increment of the checkpoint (2 over 4 visits) and the new one (1 over 1 visit) in cell 0.
    assert update.q_tables[2, 0] == pytest.approx((2.0 * 4 + 1.0 * 1) / 5)
    assert update.visits[2, 0] == 5 and resumed.increments == 2


def test_broadcasts_from_the_loop_and_a_finished_fit_reach_the_wire_in_version_order(tmp_path: Path) -> None:
    bus = InMemoryBus()
    versions: list[int] = []
    with InMemoryTransport(bus) as lt, InMemoryTransport(bus) as watcher:
        watcher.subscribe(watcher.keys.policy(), PolicyUpdate, lambda u: versions.append(u.version))
        service = LearnerService(lt, FAST, tmp_path)
        service.state.adopt(one_cell_per_action(service.config.resolved.dim))
        numbered, second_numbered = threading.Event(), threading.Event()
        publish = service.state.publish

        def slow_after_numbering() -> PolicyUpdate:
            # The first caller is held between numbering its version and sending it, as a thread preempted there;
            # a second caller that could number and send meanwhile would put the later version on the wire first.
            update = publish()
            if not numbered.is_set():
                numbered.set()
                second_numbered.wait(1.0)
            else:
                second_numbered.set()
            return update

        service.state.publish = slow_after_numbering  # type: ignore[method-assign]
        fit = threading.Thread(target=service._broadcast)
        fit.start()
        assert numbered.wait(10)
        service._broadcast()
        fit.join()
    assert versions == [1, 2]


def test_an_empty_state_checkpoints_and_restores(tmp_path: Path) -> None:
    state = PolicyState(10, PAPER, "cmommt-v1", 5, "m")
    state.adopt(one_cell_per_action())
    arrays, meta = state.to_arrays()
    assert arrays["pending_change"].shape == (0, 8)
    resumed = PolicyState(10, PAPER, "cmommt-v1", 5, "m")
    resumed.restore(arrays, meta)
    assert resumed.version == 1 and resumed.policy() is not None


def test_a_poisoned_message_is_rejected_by_its_seq_and_the_stream_flows_on(tmp_path: Path) -> None:
    import msgpack

    from protocol import Ack, Reject, encode

    good = [experience(seq=0), experience(seq=2)]
    envelope = msgpack.unpackb(encode(experience(seq=1)), raw=False)
    reward = np.array([0.0, np.nan, 0.0], np.float32)
    envelope[2]["reward"] = ["float32", [3], reward.tobytes()]  # valid msgpack, NaN reward: InvalidValues
    poison = msgpack.packb(envelope, use_bin_type=True)
    lie = msgpack.unpackb(poison, raw=False)
    lie[2]["actor_id"] = "b"  # on a's key, claiming b's stream: refused, and no Reject is sent to b
    rejects: list[Reject] = []
    acks: list[Ack] = []
    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(t.keys.reject(), Reject, rejects.append)
        t.subscribe(t.keys.ack(), Ack, acks.append)
        service = LearnerService(t, FAST, tmp_path)
        handles = connect_learner(service, t)
        t.publish(t.keys.experience("a"), good[0])
        t.inject_raw(t.keys.experience("a"), poison)
        t.inject_raw(t.keys.experience("a"), poison)  # re-sent before the Reject arrived: a duplicate, no Reject
        t.inject_raw(t.keys.experience("a"), msgpack.packb(lie, use_bin_type=True))
        t.publish(t.keys.experience("a"), good[1])
        t.publish(t.keys.experience("a"), experience(seq=3, dim=2))  # wrong state dimension: rejected by seq too
        t.publish(t.keys.experience("a"), experience(seq=3, dim=2))  # and its re-send a duplicate
        service.checkpoint()
        handles.close()  # the ExitStack connect returned: every handle, in reverse order
    assert [(r.actor_id, r.seq) for r in rejects] == [("a", 1), ("a", 3)]
    assert rejects[0].reason.startswith("InvalidValues: reward")
    assert rejects[1].reason == f"state dimension 2, expected {DIM}"
    assert [(a.actor_id, a.seq) for a in acks] == [("a", 3)]  # the cumulative ack steps over both
    figures = service.intake.figures()
    assert figures.tuples_received == 6 and figures.refused == 2 and figures.gaps == 0
    # One count per arrival: each refused message once, each re-send a duplicate; the lie is counted, but no Reject
    # went to b for it.
    assert figures.rejected_by_type == {"InvalidValues": 2, "StateDimension": 1} and figures.duplicates == 2


def test_the_run_saves_its_last_policy_not_an_earlier_one_that_scored_more(tmp_path: Path) -> None:
    """The saved policy is the one the whole run's experience made: the last, whatever an evaluation of an earlier
    version scored."""
    from algorithm.policy_file import load_policy
    from tests.algorithm.test_selection import constant, validation

    config = dataclasses.replace(FAST, final_eval_trials=3, duration=0.5, law_margin=0.0)
    scores = {a: validation(constant(a, version=1), 3) for a in range(8)}
    good, bad = max(scores, key=scores.__getitem__), min(scores, key=scores.__getitem__)
    current = [constant(good, version=3)]
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service.state.adopt(one_cell_per_action(DIM))
        service.state.policy = lambda: current[0]  # type: ignore[method-assign]
        service._evaluate()
        current[0] = constant(bad, version=4)
        report = service.run(threading.Event())
    saved, _ = load_policy(tmp_path / "policy.npz")
    assert int(np.argmax(saved.tables[0])) == bad and saved.version == 4
    assert report.saved is not None and report.saved["version"] == 4 and report.saved["margin"] == 0.0
    assert len(report.coverage_curve) == 1  # the good version's evaluation: on the curve, not a choice
    assert report.final_coverage_mean == round(
        evaluate(
            service.scenario, PolicyController(constant(bad, 1)), 3, FAST.eval_steps, seed=TEST_SEED
        ).coverage_mean,
        3,
    )


@pytest.mark.parametrize("given", [None, 0.0, 0.5])
def test_the_saved_policy_is_read_with_the_law_margin_chosen_on_validation_trials_or_given(
    tmp_path: Path, given: float | None
) -> None:
    from algorithm.policy_file import load_policy
    from algorithm.selection import LAW_MARGINS, choose_margin
    from tests.algorithm.test_selection import law_or_back

    config = dataclasses.replace(FAST, final_eval_trials=3, duration=0.5, law_margin=given)
    policy = law_or_back(0.25)  # its argmax runs from every target; a margin of 0.3 or more reads the law
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service.state.adopt(one_cell_per_action(DIM))
        service.state.policy = lambda: policy  # type: ignore[method-assign]
        report = service.run(threading.Event())
    saved, _ = load_policy(tmp_path / "policy.npz")
    assert report.saved is not None and report.base_law == "force-recall"
    if given is None:
        expected = choose_margin(service.scenario, policy, 3, FAST.eval_steps)
        assert expected.margin == 0.3 and saved.law_margin == 0.3
        assert report.saved["margin"] == 0.3
        assert report.saved["choice"] == {
            "validation_coverage": {f"{m:g}": round(expected.scores[m], 3) for m in LAW_MARGINS},
            "validation_spread": {f"{m:g}": round(expected.spreads[m], 4) for m in LAW_MARGINS},
            "validation_trials": 3,
            "validation_seed": 1000,
        }
    else:
        assert saved.law_margin == given and report.saved["margin"] == given and report.saved["choice"] is None
    # Below the gap of 0.25 every decision leaves law for back; at or above it none does.
    learned = report.final_comparison["learned"]
    assert learned["off_law_pct"] == (100.0 if saved.law_margin < 0.25 else 0.0)
    assert learned["shared_off_law_pct"] == (
        100.0 if saved.law_margin < 0.25 and learned["shared_decisions_pct"] else 0.0
    )
    # The final figure is that of the policy as saved, margin and all, on the reported test trials.
    read = dataclasses.replace(policy, law_margin=saved.law_margin)
    assert report.final_coverage_mean == round(
        evaluate(service.scenario, PolicyController(read), 3, FAST.eval_steps, seed=TEST_SEED).coverage_mean, 3
    )
    base = report.final_comparison["force-recall"]
    law = evaluate(service.scenario, HAND_MADE["force-recall"], 3, FAST.eval_steps, seed=TEST_SEED)
    assert base["coverage"] == round(law.coverage_mean, 3)


def test_each_robot_acts_on_its_own_row_and_the_merged_team_table_is_scored_beside_it(tmp_path: Path) -> None:
    """Option 2 as the paper has it: the policy file holds every robot's row and each robot acts on its own; the
    report scores the rows merged by their visits beside it, on the same trials."""
    from algorithm.policy_file import load_policy

    config = dataclasses.replace(FAST, final_eval_trials=4, duration=0.5, law_margin=0.0)
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        assert service.state.team is False
        service.state.adopt(one_cell_per_action(DIM))
        service.state.publish()  # version 1: the increments are learned over it
        # Robot 3 alone values move 5 ("back") highest; the others' visits outweigh it in the merge.
        service.state.add_increment(increment("a", 0, [0.0] * 5 + [9.0, 0.0, 0.0], [1] * 8, robot=3))
        service.state.add_increment(increment("a", 1, [1.0] + [0.0] * 7, [50] * 8, robot=4))
        report = service.run(threading.Event())
    saved, _ = load_policy(tmp_path / "policy.npz")
    assert saved.tables.shape[0] == 10 and saved.robot_table.tolist() == list(range(10))
    assert int(np.argmax(saved.tables[3])) == 5 and int(np.argmax(saved.tables[4])) == 0
    team = saved.team()
    assert team.tables.shape[0] == 1 and int(np.argmax(team.tables[0])) == 0
    per_robot = evaluate(service.scenario, PolicyController(saved), 4, FAST.eval_steps, seed=TEST_SEED)
    merged = evaluate(service.scenario, PolicyController(team), 4, FAST.eval_steps, seed=TEST_SEED)
    assert report.final_coverage_mean == round(per_robot.coverage_mean, 3)
    assert report.team_table is not None and report.team_table["coverage"] == round(merged.coverage_mean, 3)
    mean, se = per_robot.minus(merged)
    assert report.team_table["per_robot_minus"] == round(mean, 3)
    assert report.team_table["per_robot_minus_se"] == round(se, 3)


def test_a_run_stopped_by_a_signal_saves_its_last_tables_without_a_margin_choice(tmp_path: Path) -> None:
    from algorithm.policy_file import load_policy
    from algorithm.selection import FALLBACK_MARGIN
    from tests.algorithm.test_selection import law_or_back

    config = dataclasses.replace(FAST, final_eval_trials=3)
    policy = law_or_back(0.25)
    stop = threading.Event()
    stop.set()
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service.state.adopt(one_cell_per_action(DIM))
        service.state.policy = lambda: policy  # type: ignore[method-assign]
        service.rule = dataclasses.replace(service.rule, trials=10**6)  # a choice would never end
        report = service.run(stop)
    saved, _ = load_policy(tmp_path / "policy.npz")
    assert saved.law_margin == FALLBACK_MARGIN and report.saved is not None
    assert report.saved["margin"] == FALLBACK_MARGIN and report.saved["choice"] is None
    assert "stopped" in report.saved["reason"] and report.final_coverage_mean is not None


def test_the_final_evaluation_reports_its_progress_and_a_second_stop_skips_it_after_the_checkpoint(
    tmp_path: Path,
) -> None:
    # The wind-down's scoring is seconds of trials: a launcher shows how far it got from the statuses, and a user who
    # stops again gets the policy and the checkpoint without it.
    from algorithm.policy_file import load_policy
    from learner.checkpoint import CHECKPOINT
    from learner.report import LearnerStatus
    from protocol import Status
    from sim import CONTROLLERS
    from tests.algorithm.test_selection import law_or_back
    from tools.system import Stop

    config = dataclasses.replace(FAST, final_eval_trials=3, law_margin=0.5)
    policy = law_or_back(0.25)
    for again in (False, True):
        run_dir = tmp_path / str(again)
        stop = Stop()
        stop.set()
        if again:
            stop.urgent.set()
        statuses: list[Status] = []
        with InMemoryTransport(InMemoryBus()) as t:
            t.subscribe(t.keys.status(), Status, statuses.append)
            service = LearnerService(t, config, run_dir)
            service.state.adopt(one_cell_per_action(DIM))
            service.state.policy = lambda: policy  # type: ignore[method-assign]
            report = service.run(stop)
        shares = [s for m in statuses if (s := LearnerStatus.from_counters(m.counters).scoring) is not None]
        saved, _ = load_policy(run_dir / "policy.npz")
        assert saved.law_margin == 0.5 and (run_dir / CHECKPOINT).exists()
        if again:
            assert report.final_coverage_mean is None and shares == [0.0]
        else:
            parts = 1 + len(CONTROLLERS)  # the policy (one row), then every reference on the same trials
            assert report.final_coverage_mean is not None
            # Each part's share once it is done; the statuses between parts repeat the share reached.
            assert shares == sorted(shares) and list(dict.fromkeys(shares)) == [
                0.0,
                *(k / parts for k in range(1, parts + 1)),
            ]


def test_the_learner_keeps_its_status_going_while_it_scores_at_the_end(tmp_path: Path) -> None:
    # The end's work (the margin choice, the scoring) holds the learner's loop for seconds: a peer must still hear a
    # status every interval, or it takes the learner for dead.
    from learner.report import LearnerStatus
    from protocol import Status
    from tests.algorithm.test_selection import law_or_back
    from tools.system import Stop

    config = dataclasses.replace(FAST, final_eval_trials=3, law_margin=0.5, status_interval=0.1)
    heard: list[tuple[float, float | None]] = []
    stop = Stop()
    stop.set()
    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(
            t.keys.status(),
            Status,
            lambda m: heard.append((time.monotonic(), LearnerStatus.from_counters(m.counters).scoring)),
        )
        service = LearnerService(t, config, tmp_path)
        service.state.adopt(one_cell_per_action(DIM))
        policy = law_or_back(0.25)
        service.state.policy = lambda: policy  # type: ignore[method-assign]
        final = service.evaluator.final

        def slow_final(policy: Any, *args: Any) -> float:
            time.sleep(1.5)
            return final(policy, *args)

        service.evaluator.final = slow_final  # type: ignore[method-assign]
        service.run(stop)
    scoring = [at for at, share in heard if share is not None]
    gaps = [b - a for a, b in itertools.pairwise(scoring)]
    assert len(scoring) >= 10 and max(gaps) < 0.5, (len(scoring), max(gaps))


def test_acks_policies_and_status_go_out_while_an_evaluation_is_under_way(tmp_path: Path) -> None:
    # An evaluation is seconds of trials; the checkpoints (and the acks after them), the policies and the status go
    # on meanwhile, or every actor's outbox would fill with unacknowledged experience and a client would see the
    # learner fall silent.
    from protocol import Ack, Status

    config = dataclasses.replace(FAST, eval_interval=0.01, checkpoint_interval=0.05, status_interval=0.1)
    acks: list[Ack] = []
    heard: list[tuple[str, float]] = []
    evaluating, release, returned = threading.Event(), threading.Event(), threading.Event()

    def held(policy: Any, at: float, stop: Any = None) -> float:
        evaluating.set()
        release.wait(60.0)
        returned.set()
        return 0.0

    with InMemoryTransport(InMemoryBus()) as t:
        t.subscribe(t.keys.ack(), Ack, acks.append)
        t.subscribe(t.keys.policy(), PolicyUpdate, lambda u: heard.append(("policy", time.monotonic())))
        t.subscribe(t.keys.status(), Status, lambda u: heard.append(("status", time.monotonic())))
        service = LearnerService(t, config, tmp_path)
        handles = connect_learner(service, t)
        service.state.adopt(one_cell_per_action(DIM))
        service.evaluator.periodic = held  # type: ignore[method-assign]
        stop = threading.Event()
        thread = threading.Thread(target=service.run, args=(stop,))
        thread.start()
        try:
            assert evaluating.wait(60.0)
            t.publish(t.keys.experience("a"), experience(seq=0))
            t.publish(t.keys.experience("a"), experience(seq=1))
            deadline = time.monotonic() + 30.0
            while not any(a.seq == 1 for a in acks) and time.monotonic() < deadline:
                time.sleep(0.01)
            acked_while_held = any(a.seq == 1 for a in acks) and not returned.is_set()
            held_since = time.monotonic()
            while len([k for k, at in heard if at > held_since]) < 6 and time.monotonic() < deadline:
                time.sleep(0.01)
            during = {k for k, at in heard if at > held_since} if not returned.is_set() else set()
        finally:
            release.set()
            stop.set()
            thread.join()
            handles.close()
    assert acked_while_held
    assert during == {"policy", "status"}  # both kept going out while the evaluation held its thread
    assert service.intake.figures().tuples_received == 6


def test_a_checkpoint_that_fails_ends_the_run_with_its_error(tmp_path: Path) -> None:
    def full(arrays: Any, meta: Any) -> Path:
        raise OSError(28, "No space left on device")

    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, FAST, tmp_path)
        service.checkpointer.save = full  # type: ignore[method-assign]
        with pytest.raises(OSError, match="No space left"):
            service.run(threading.Event())
