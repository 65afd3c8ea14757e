"""A new formulation part is one entry of its registry and nothing else: a toy state, reward, action set and set of
trial rules, registered here only, run through a learning trial, the experience slice, a policy file and the
Gymnasium adapter's checker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.policy_file import load_policy, save_policy
from algorithm.trials import ExperienceSlice, SliceConfig
from sim import ScenarioConfig, scenario
from sim.actions import ACTION_SETS, ActionSet
from sim.envs.gym_env import CmommtSingleRobotEnv
from sim.features import FEATURIZER_REGISTRY, REWARDS, Featurizer, Reward
from sim.formulation import TRIAL_RULES, Formulation, TrialRules
from sim.world import Observation

_EIGHTHS = np.arange(8) * np.pi / 4


def _seen(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return obs.n_seen[..., None].astype(np.float32)


def _twice_seen(cfg: ScenarioConfig, obs: Observation) -> np.ndarray:
    return 2.0 * obs.n_seen.astype(np.float32)


def _counts_none(cfg: ScenarioConfig, states: np.ndarray) -> np.ndarray:
    return states[..., 0] == 0


TOY_STATE = Featurizer("toy-count", ("targets_in_view",), _seen, "toy-twice", _counts_none)
TOY_REWARD = Reward("toy-twice", _twice_seen, per_decision=True)
TOY_MOVES = ActionSet(
    "toy-rose",
    tuple(f"m{k}" for k in range(8)),
    np.stack([np.cos(_EIGHTHS + np.pi / 8), np.sin(_EIGHTHS + np.pi / 8)], axis=-1),
    relative=False,
)
TOY_RULES = TrialRules("toy-search", lost_ends_trial=False, timeout_terminal=True)


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch) -> Formulation:
    """The toy parts, each added to its registry and to nothing else, for this test only."""
    monkeypatch.setitem(FEATURIZER_REGISTRY, TOY_STATE.name, TOY_STATE)
    monkeypatch.setitem(REWARDS, TOY_REWARD.name, TOY_REWARD)
    monkeypatch.setitem(ACTION_SETS, TOY_MOVES.name, TOY_MOVES)
    monkeypatch.setitem(TRIAL_RULES, TOY_RULES.name, TOY_RULES)
    return Formulation.of("toy-count", "paper", "toy-rose", trial_rules="toy-search")


def test_registered_toy_parts_run_a_learning_trial_end_to_end(toy: Formulation, tmp_path: Path) -> None:
    assert (toy.featurizer, toy.reward, toy.actions, toy.trial_rules) == (TOY_STATE, TOY_REWARD, TOY_MOVES, TOY_RULES)
    assert toy.names == ("toy-count", "toy-twice", "toy-rose") and toy.dim == 1  # "paper": the state's own reward
    cfg = scenario(n_robots=4, n_targets=4)
    batch = ExperienceSlice(cfg, SliceConfig(toy, n_arenas=8), seed=0).run_trial()
    assert batch.state.shape[1] == 1 and len(batch) > 0
    np.testing.assert_array_equal(batch.state, np.round(batch.state))  # counts of targets in view
    # A per-decision reward's mean over an action of a state that counts targets lies within twice the counts seen.
    assert batch.reward.min() >= 0.0 and batch.reward.max() <= 2.0 * cfg.n_targets
    # Its rules: losing every target ends no trial, so every learner decides the whole trial through and ends once.
    learners = 8 * cfg.n_robots
    assert len(batch) == learners * (cfg.learning_steps // cfg.action_steps) and batch.done.sum() == learners
    # A policy over it goes through the policy file and back by its names.
    disc = Discretization.from_per_action([np.zeros((1, 1), np.float32)] * 8)
    policy = Policy(toy, disc, np.zeros((cfg.n_robots, disc.size), np.float32), np.arange(cfg.n_robots))
    loaded, header = load_policy(save_policy(policy, cfg, tmp_path / "toy.npz"))
    assert loaded.formulation.names == toy.names and header["featurizer"]["state"] == ["targets_in_view"]
    assert [a["name"] for a in header["actions"]] == list(TOY_MOVES.moves)


def test_the_gymnasium_adapter_runs_a_toy_formulation_through_its_checker(toy: Formulation) -> None:
    env = CmommtSingleRobotEnv(formulation=toy)
    assert env.observation_space.shape == (1,)
    check_env(env, skip_render_check=True)
