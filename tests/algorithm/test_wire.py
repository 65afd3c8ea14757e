"""Domain <-> wire conversions: both directions, through the real codec, and the protocol's constants."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from algorithm.qtable import merge_increments
from algorithm.transitions import Transitions
from algorithm.wire import (
    experience_batches,
    formulation_mismatch,
    increment_arrays,
    increment_message,
    policy_from_update,
    policy_update,
    transitions_from_batch,
)
from protocol import N_ACTIONS, Header, InvalidValues, decode_as, encode
from protocol.messages import ExperienceBatch, PolicyUpdate, QTableIncrement
from sim import COMPASS, scenario
from sim.actions import ACTION_SETS
from sim.features import FEATURIZERS, REWARDS
from sim.formulation import FORMULATIONS, Formulation
from tests.fakes import make_policy


def transitions(n: int, dim: int = 6, seed: int = 0) -> Transitions:
    rng = np.random.default_rng(seed)
    return Transitions(
        robot=rng.integers(0, 10, n).astype(np.int16),
        state=rng.normal(size=(n, dim)).astype(np.float32),
        action=rng.integers(0, N_ACTIONS, n).astype(np.uint8),
        reward=rng.normal(size=n).astype(np.float32),
        next_state=rng.normal(size=(n, dim)).astype(np.float32),
        done=rng.random(n) < 0.2,
    )


def test_policy_round_trips_through_the_wire() -> None:
    policy = make_policy(np.random.default_rng(1))  # one table per robot (option 2)
    update = decode_as(encode(policy_update(policy, "cmommt-v1")), PolicyUpdate)
    assert formulation_mismatch(policy.formulation, update) == ""
    back = policy_from_update(update, n_robots=policy.n_robots, formulation=policy.formulation, method=policy.method)
    for name in ("prototypes", "labels", "offsets", "scale"):
        np.testing.assert_array_equal(getattr(back.discretization, name), getattr(policy.discretization, name))
    np.testing.assert_array_equal(back.tables, policy.tables)
    assert policy.visits is not None and back.visits is not None
    np.testing.assert_array_equal(back.visits, policy.visits)
    assert (back.version, back.formulation, back.action_steps) == (policy.version, policy.formulation, 5)
    assert (update.featurizer, update.reward_function, update.action_set) == ("collab6d", "eq2", "compass")
    assert update.scenario == "cmommt-v1" and update.robots.tolist() == list(range(10))


def test_a_shared_table_goes_out_as_every_robots_row() -> None:
    policy = make_policy(np.random.default_rng(2), robots=4, rows=1)  # option 1: one table for all
    update = policy_update(policy, "cmommt-v1")
    assert update.q_tables.shape == (4, policy.discretization.size)
    np.testing.assert_array_equal(update.q_tables, np.repeat(policy.tables, 4, axis=0))
    back = policy_from_update(update, n_robots=6, formulation=policy.formulation)  # robots the update does not name
    # take the mean row
    np.testing.assert_allclose(back.tables[5], policy.tables[0], rtol=1e-6)
    assert back.visits is not None and back.visits[5].sum() == 0


def test_transitions_round_trip_in_batches_with_the_headers_they_are_given() -> None:
    data = transitions(2500)
    parts = experience_batches(data, 1000, FORMULATIONS["shared-difference"])
    batches = [build(Header("a0", 9, 4 + k, 3)) for k, build in enumerate(parts)]
    assert [b.seq for b in batches] == [4, 5, 6] and [b.n_tuples for b in batches] == [1000, 1000, 500]
    decoded = [transitions_from_batch(decode_as(encode(b), ExperienceBatch)) for b in batches]
    joined = Transitions.concat(decoded)
    for name in ("robot", "state", "action", "reward", "next_state", "done"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(data, name))
    assert {b.policy_version for b in batches} == {3} and {b.incarnation for b in batches} == {9}
    assert {(b.featurizer, b.reward_function, b.action_set) for b in batches} == {("shared8d", "difference", "compass")}
    # The messages hold views of the trial's tuples, not copies: an outbox keeps them until they are acknowledged.
    for name in ("state", "next_state", "reward"):
        assert all(np.shares_memory(getattr(b, name), getattr(data, name)) for b in batches)


def test_an_invalid_tuple_is_caught_in_the_actor_before_the_wire() -> None:
    data = transitions(10)
    data.reward[3] = np.nan
    first, second = experience_batches(data, 8, FORMULATIONS["paper"])
    with pytest.raises(InvalidValues, match="reward"):
        first(Header("a0", 1, 0, 0))
    assert second(Header("a0", 1, 0, 0)).n_tuples == 2  # only the part holding the NaN is refused


def test_increments_round_trip_and_saturate_visits() -> None:
    change = np.array([0.5, -1.25, 0.0], np.float64)
    visits = np.array([3, 2**40, 0], np.uint64)
    offsets = np.array([0, 1, 2, 3, 3, 3, 3, 3, 3], np.int64)
    msg = increment_message(Header("a0", 1, 2, 5), robot=4, change=change, visits=visits, offsets=offsets)
    assert (msg.actor_id, msg.incarnation, msg.seq, msg.policy_version) == ("a0", 1, 2, 5)
    robot, back_change, back_visits = increment_arrays(decode_as(encode(msg), QTableIncrement))
    assert robot == 4
    np.testing.assert_array_equal(back_change, change)
    assert back_visits.tolist() == [3.0, float(np.iinfo(np.uint32).max), 0.0]
    tables, total = merge_increments(np.zeros((5, 3)), np.zeros((5, 3), np.uint64), [(robot, back_change, back_visits)])
    np.testing.assert_array_equal(tables[4], [0.5, -1.25, 0.0])
    assert total[4, 0] == 3


def test_the_builders_write_the_pinned_wire_bytes() -> None:
    golden = Path(__file__).parents[1] / "protocol" / "golden"
    tuples = Transitions(
        robot=np.array([0, 5], np.int16),
        state=np.array([[0.5, -1.0], [2.0, 0.25]], np.float32),
        action=np.array([1, 7], np.uint8),
        reward=np.array([1.0, -0.5], np.float32),
        next_state=np.array([[0.75, -1.0], [2.0, 0.0]], np.float32),
        done=np.array([False, True]),
    )
    (build,) = experience_batches(tuples, 2, Formulation.of("local2d", "observed", "compass"))
    batch = build(Header("actor-0", 0x0123456789ABCDEF, seq=7, policy_version=3))
    assert encode(batch) == (golden / "experience.msgpack").read_bytes()
    increment = increment_message(
        Header("actor-0", 0x0123456789ABCDEF, seq=8, policy_version=3),
        robot=5,
        change=np.linspace(-1.0, 1.0, N_ACTIONS),
        visits=np.arange(N_ACTIONS),
        offsets=np.arange(N_ACTIONS + 1),
    )
    assert encode(increment) == (golden / "qinc.msgpack").read_bytes()


def test_one_check_at_either_end_names_the_first_part_of_another_formulation() -> None:
    data = transitions(4, dim=8)
    (build,) = experience_batches(data, 4, FORMULATIONS["shared-difference"])
    batch = build(Header("a0", 1, 0, 0))
    update = policy_update(make_policy(np.random.default_rng(0)), "cmommt-v1")  # the paper's
    assert formulation_mismatch(FORMULATIONS["shared-difference"], batch) == ""
    assert formulation_mismatch(FORMULATIONS["paper"], batch) == "featurizer shared8d, expected collab6d"
    relative = FORMULATIONS["paper"].replace(actions="relative")
    assert formulation_mismatch(relative, update) == "action_set compass, expected relative"
    assert formulation_mismatch(FORMULATIONS["paper"].replace(reward="observed"), update) == (
        "reward_function eq2, expected observed"
    )
    # The trial rules and the test-time decision period are no part of what the wire carries.
    assert formulation_mismatch(FORMULATIONS["paper"].replace(trial_rules="search-on", act_every=1), update) == ""


def test_the_protocols_constants_are_the_simulators() -> None:
    assert len(COMPASS) == N_ACTIONS
    assert {len(actions.moves) for actions in ACTION_SETS.values()} == {N_ACTIONS}


def test_the_formulation_names_docs_protocol_lists_are_the_registries() -> None:
    """docs/reference/protocol.md §4 lists the names a formulation may carry: exactly sim's registries, dimensions and
    moves."""
    text = (Path(__file__).parents[2] / "docs" / "reference" / "protocol.md").read_text()
    table = text[text.index("### Formulation") : text.index("### `ack`")]
    rows = dict(re.findall(r"^\| `(\w+)`\s+\| (.+?) \|$", table, re.M))
    documented = {
        kind: re.findall(r"`([a-z0-9-]+)`(?: \(d = (\d+)\))?", rows[kind].split("(`")[0])
        for kind in ("featurizer", "reward_function", "action_set")
    }
    assert documented["featurizer"] == [(name, str(d)) for name, d in FEATURIZERS.items()]
    assert [name for name, _ in documented["reward_function"]] == list(REWARDS)
    assert [name for name, _ in documented["action_set"]] == list(ACTION_SETS)
    assert ", ".join(ACTION_SETS["compass"].moves) in rows["action_set"]
    assert scenario().n_robots <= np.iinfo(np.int16).max  # robot ids travel as int16


@pytest.mark.parametrize(
    "modules",
    [
        "actors.actor, actors.wiring, ennc_ql.actor",  # everything an actor process loads
        "algorithm.policy, algorithm.agent, algorithm.trials, algorithm.wire, algorithm.policy_file, algorithm",
        "learner.config, algorithm.phase1, algorithm.experiments",  # configurations are read without fitting
        "ennc_ql.router, ennc_ql.cli",
    ],
)
def test_acting_never_imports_torch(modules: str) -> None:
    code = f"import sys, {modules}; import ennc_ql.cli as c; c.build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == "False"


def test_an_actor_reading_a_configuration_never_imports_cryptography() -> None:
    """Checking a configuration file against every role's settings (an actor given up's file) loads the cluster
    library, whose secure sets are written with cryptography: only writing them may load it (9 MB resident)."""
    code = (
        "import sys, ennc_ql.actor, ennc_ql.command as c; c._roles(); import tools.cluster, tools.secure; "
        "print('cryptography' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == "False"
