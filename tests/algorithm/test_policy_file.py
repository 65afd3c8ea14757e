"""The portable policy file round trip, its errors, and acting with a learned policy."""

from __future__ import annotations

import dataclasses
import json
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from algorithm.discretization import Discretization
from algorithm.policy import Policy, PolicyController
from algorithm.policy_file import FORMAT_VERSION, PolicyFileError, load_policy, save_policy, scenario_from_header
from sim import FORMULATIONS, Formulation, evaluate, scenario
from tests.fakes import make_policy


def rewritten(path: Path, out: Path, edit: Callable[[dict[str, Any]], None]) -> Path:
    """A copy of the policy file at ``path`` whose header ``edit`` changed in place, as an older or foreign writer
    would have written it."""
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    header = json.loads(arrays["header"].tobytes())
    edit(header)
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(out, **arrays)
    return out


def test_round_trip_keeps_every_array_and_field(tmp_path: Path) -> None:
    cfg = scenario(sensor_noise_std=2.0)
    policy = make_policy(np.random.default_rng(0))
    path = save_policy(policy, cfg, tmp_path / "p.npz")
    loaded, header = load_policy(path)
    for name in ("prototypes", "labels", "offsets", "scale"):
        np.testing.assert_array_equal(getattr(loaded.discretization, name), getattr(policy.discretization, name))
    np.testing.assert_array_equal(loaded.tables, policy.tables)
    np.testing.assert_array_equal(loaded.robot_table, policy.robot_table)
    assert loaded.visits is not None and policy.visits is not None
    np.testing.assert_array_equal(loaded.visits, policy.visits)
    assert (loaded.version, loaded.method, loaded.meta, loaded.formulation) == (
        7,
        policy.method,
        {"seed": 3},
        policy.formulation,
    )
    assert header["prototypes_per_action"] == list(policy.discretization.sizes())
    assert header["featurizer"]["mask_value"] == 1000.0 and len(header["featurizer"]["state"]) == 6
    assert [a["name"] for a in header["actions"]] == ["N", "NE", "E", "SE", "S", "SW", "W", "NW"]
    assert scenario_from_header(header) == cfg
    states = np.random.default_rng(1).normal(0, 100, (50, 6))
    robots = np.arange(50) % 10
    np.testing.assert_array_equal(loaded.greedy(states, robots), policy.greedy(states, robots))


def test_the_header_names_the_reward_and_a_file_without_one_had_its_featurizers_paper_reward(tmp_path: Path) -> None:
    paper = make_policy(np.random.default_rng(0))
    policy = dataclasses.replace(paper, formulation=paper.formulation.replace(reward="difference"))
    path = save_policy(policy, scenario(), tmp_path / "p.npz")
    loaded, header = load_policy(path)
    assert (
        header["reward"] == {"name": "difference", "per_decision": False}
        and loaded.formulation.reward.name == "difference"
    )
    old = rewritten(path, tmp_path / "old.npz", lambda h: h.pop("reward"))
    assert load_policy(old)[0].formulation.reward.name == "eq2"
    money = rewritten(path, tmp_path / "money.npz", lambda h: h.update(reward={"name": "money", "per_decision": False}))
    with pytest.raises(PolicyFileError, match="unknown reward 'money'"):
        load_policy(money)


def test_the_header_names_the_action_set_and_a_file_without_one_used_the_compass(tmp_path: Path) -> None:
    paper = make_policy(np.random.default_rng(0))
    policy = dataclasses.replace(paper, formulation=paper.formulation.replace(actions="relative"))
    path = save_policy(policy, scenario(), tmp_path / "p.npz")
    loaded, header = load_policy(path)
    assert (
        header["action_set"] == {"name": "relative", "frame": "target"}
        and loaded.formulation.actions.name == "relative"
    )
    assert [a["name"] for a in header["actions"]][:3] == ["toward", "toward-left", "left"]
    assert header["actions"][2]["direction"] == pytest.approx([0.0, 1.0])  # left: +y of the target frame
    old = rewritten(path, tmp_path / "old.npz", lambda h: h.pop("action_set"))
    assert load_policy(old)[0].formulation.actions.name == "compass"


def test_the_header_carries_the_law_margin_and_a_file_without_one_is_read_by_the_argmax(tmp_path: Path) -> None:
    paper = make_policy(np.random.default_rng(0))
    law = paper.formulation.replace(featurizer="frame11d-recall", actions="law-track")
    disc = Discretization.from_per_action([np.zeros((1, law.dim), np.float32)] * 8)
    policy = dataclasses.replace(
        paper,
        formulation=law,
        discretization=disc,
        tables=np.zeros((1, 8), np.float32),
        robot_table=np.zeros(10, np.int64),
        visits=None,
        law_margin=0.3,
    )
    path = save_policy(policy, scenario(), tmp_path / "p.npz")
    loaded, header = load_policy(path)
    assert header["law_margin"] == 0.3 and loaded.law_margin == 0.3
    assert load_policy(rewritten(path, tmp_path / "old.npz", lambda h: h.pop("law_margin")))[0].law_margin == 0.0
    bad = rewritten(path, tmp_path / "bad.npz", lambda h: h.update(law_margin=-1))
    with pytest.raises(PolicyFileError, match="law_margin must be a finite number >= 0"):
        load_policy(bad)


def test_the_file_is_a_plain_npz_with_a_json_header(tmp_path: Path) -> None:
    path = save_policy(make_policy(np.random.default_rng(0)), scenario(), tmp_path / "p.npz")
    with zipfile.ZipFile(path) as zf:
        assert {"header.npy", "prototypes.npy", "tables.npy", "offsets.npy"} <= set(zf.namelist())
    with np.load(path) as data:
        header = json.loads(data["header"].tobytes())
    assert header["format"] == "ennc-ql-policy" and header["format_version"] == FORMAT_VERSION


def test_bad_files_get_a_clear_error(tmp_path: Path) -> None:
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(PolicyFileError, match=r"not a policy file \(not an .npz archive of plain arrays\)$"):
        load_policy(junk)
    with pytest.raises(PolicyFileError, match=r"cannot be read \(No such file or directory\)$"):
        load_policy(tmp_path / "missing.npz")
    path = save_policy(make_policy(np.random.default_rng(0)), scenario(), tmp_path / "p.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    header = json.loads(arrays["header"].tobytes())
    header["format_version"] = 99
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), np.uint8)
    np.savez(tmp_path / "future.npz", **arrays)
    with pytest.raises(PolicyFileError, match="version 99"):
        load_policy(tmp_path / "future.npz")
    del arrays["tables"]
    np.savez(tmp_path / "partial.npz", **arrays)
    with pytest.raises(PolicyFileError, match=r"not a policy file \(no tables; "):
        load_policy(tmp_path / "partial.npz")


@pytest.mark.parametrize(
    ("array", "value", "message"),
    [
        (
            "tables",
            np.nan,
            r": the Q table of robot 4 holds NaN \(1 of \d+ values\); a policy acts on finite values only$",
        ),
        ("tables", -np.inf, r": the Q table of robot 4 holds infinity \(1 of \d+ values\)"),
        # The discretization refuses its own as it is built.
        ("prototypes", np.inf, r": inconsistent policy file \(prototypes and labels must be finite\)$"),
        ("labels", np.nan, r": inconsistent policy file \(prototypes and labels must be finite\)$"),
        ("scale", np.nan, r": inconsistent policy file \(scale must be a positive finite \(6,\) array\)$"),
    ],
)
def test_a_file_whose_arrays_are_not_finite_is_refused_naming_them(
    tmp_path: Path, array: str, value: float, message: str
) -> None:
    """An argmax over a NaN picks a move at random, and a distance to an infinite prototype is no distance: a file
    holding one is refused as it is read, wherever it is read (eval, bench actor, a sweep's task)."""
    path = save_policy(make_policy(np.random.default_rng(0)), scenario(), tmp_path / "p.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    arrays[array][(4, 1) if array == "tables" else 0] = value  # robot 4's own table: one row per robot
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(PolicyFileError, match=message):
        load_policy(tmp_path / "bad.npz")


def test_greedy_uses_each_robots_own_table() -> None:
    disc = Discretization.from_per_action([np.zeros((1, 2))] * 8)
    tables = np.zeros((2, 8), np.float32)
    tables[0, 3] = 1.0  # robot 0 prefers action 3
    tables[1, 6] = 1.0  # robot 1 prefers action 6
    policy = Policy(Formulation.of("local2d", "paper", "compass"), disc, tables, np.array([0, 1]))
    np.testing.assert_array_equal(policy.greedy(np.zeros((4, 2)), np.array([0, 1, 0, 1])), [3, 6, 3, 6])


def test_the_team_policy_merges_the_robots_rows_by_their_visits() -> None:
    disc = Discretization.from_per_action([np.zeros((1, 2))] * 8)
    tables = np.zeros((3, 8), np.float32)
    tables[:, 0] = [1.0, 4.0, 10.0]  # visited 1, 3 and 0 times: (1 * 1 + 4 * 3) / 4
    tables[:, 1] = [2.0, 6.0, 7.0]  # visited by no robot: the rows' mean
    visits = np.zeros((3, 8), np.uint64)
    visits[:, 0] = [1, 3, 0]
    policy = Policy(Formulation.of("local2d", "paper", "compass"), disc, tables, np.array([0, 1, 2, 0]), visits=visits)
    team = policy.team()
    assert team.tables.shape == (1, 8) and team.robot_table.tolist() == [0, 0, 0, 0]
    assert team.tables[0, 0] == pytest.approx(13 / 4) and team.tables[0, 1] == pytest.approx(5.0)
    assert team.visits is not None and team.visits[0, 0] == 4
    np.testing.assert_array_equal(team.greedy(np.zeros((4, 2)), np.arange(4)), [1, 1, 1, 1])  # 5.0 over 3.25
    unweighted = dataclasses.replace(policy, visits=None).team()
    assert unweighted.tables[0, 0] == pytest.approx(5.0) and unweighted.visits is None
    assert team.team() is team


def test_policy_controller_holds_actions_and_searches_when_lost() -> None:
    cfg = scenario()
    disc = Discretization.from_per_action([np.zeros((1, 6))] * 8)
    tables = np.zeros((1, 8), np.float32)
    tables[0, 2] = 1.0  # always East
    policy = Policy(FORMULATIONS["paper"], disc, tables, np.zeros(10, np.int64))
    from sim import reset, sense

    rng = np.random.default_rng(0)
    world = reset(cfg, 20, rng)
    controller = PolicyController(policy)
    memory = controller.init(cfg, world, rng)
    velocity, memory = controller.act(cfg, world, sense(cfg, world), memory, rng)
    seeing = sense(cfg, world).n_seen > 0
    assert seeing.any() and (~seeing).any()
    np.testing.assert_allclose(velocity[seeing], np.tile([cfg.robot_speed, 0.0], (int(seeing.sum()), 1)), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(velocity[~seeing], axis=-1), cfg.robot_speed)
    stay = PolicyController(Policy(FORMULATIONS["paper"], disc, tables, np.zeros(10, np.int64), lost_behaviour="stay"))
    v_stay, _ = stay.act(cfg, world, sense(cfg, world), stay.init(cfg, world, rng), rng)
    assert (v_stay[~seeing] == 0).all()
    # A learned always-East policy is a valid controller for the test protocol.
    result = evaluate(cfg, controller, trials=2, steps=50, seed=0)
    assert 0.0 <= result.coverage_mean <= 100.0
