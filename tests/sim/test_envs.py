"""The Gymnasium and PettingZoo adapters pass the official checkers, follow the trial rules of the experience slice
(same seed, same actions: same trajectory) and carry an off-the-shelf learner."""

from __future__ import annotations

from collections.abc import Iterator

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test

import sim.envs
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.trials import ExperienceSlice, SliceConfig
from sim import FORMULATIONS, Formulation, ScenarioConfig, WorldState, scenario
from sim.envs import pettingzoo_env
from sim.envs.gym_env import CmommtSingleRobotEnv
from sim.envs.pettingzoo_env import CmommtParallelEnv
from sim.formulation import default_formulation

PAPER = FORMULATIONS["paper"]
LOCAL = Formulation.of("local2d", "paper", "compass")


def observed_share(cfg: ScenarioConfig, world: WorldState) -> float:
    """% of targets within sensing range of some robot in arena 0, from the positions alone."""
    gap = np.linalg.norm(world.robot_pos[0, :, None] - world.target_pos[0, None], axis=-1)
    return 100.0 * int((gap <= cfg.sensing_range).any(axis=0).sum()) / cfg.n_targets


def test_gymnasium_env_passes_the_checker() -> None:
    env = CmommtSingleRobotEnv()
    assert env.formulation == default_formulation() and env.observation_space.shape == (default_formulation().dim,)
    check_env(env, skip_render_check=True)
    check_env(CmommtSingleRobotEnv(formulation=LOCAL, others="a-cmommt"), skip_render_check=True)
    shared = Formulation.of("shared8d", "difference-decision", "compass", trial_rules="search-on")
    check_env(CmommtSingleRobotEnv(formulation=shared), skip_render_check=True)


def test_the_registered_gymnasium_id_makes_the_env() -> None:
    assert sim.envs.GYM_IDS == ("cmommt/SingleRobot-v1",)
    env = gymnasium.make("cmommt/SingleRobot-v1", formulation=LOCAL)
    assert isinstance(env.unwrapped, CmommtSingleRobotEnv)
    assert env.unwrapped.formulation == LOCAL
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2,) and env.observation_space.contains(obs)
    check_env(gymnasium.make("cmommt/SingleRobot-v1").unwrapped, skip_render_check=True)


def test_pettingzoo_env_passes_the_api_and_seed_tests() -> None:
    parallel_api_test(pettingzoo_env.parallel_env(), num_cycles=300)
    shared = Formulation.of("shared8d", "difference", "compass")
    parallel_api_test(pettingzoo_env.parallel_env(formulation=shared), num_cycles=300)
    parallel_seed_test(pettingzoo_env.parallel_env)
    api_test(pettingzoo_env.env(), num_cycles=300)
    assert isinstance(pettingzoo_env.parallel_env(formulation=LOCAL), CmommtParallelEnv)
    aec = pettingzoo_env.env()
    aec.reset(seed=0)
    assert aec.agent_selection == "robot_0" and aec.observe("robot_0").shape == (default_formulation().dim,)


def test_info_carries_the_coverage_of_metric_a() -> None:
    env = CmommtSingleRobotEnv()
    _, info = env.reset(seed=3)
    assert info["coverage"] == observed_share(env.cfg, env.unwrapped._state.world) >= 10.0
    _, _, _, _, info = env.step(np.int64(0))
    assert info["coverage"] == observed_share(env.cfg, env.unwrapped._state.world)
    par = CmommtParallelEnv()
    _, infos = par.reset(seed=3)
    shares = {info["coverage"] for info in infos.values()}
    assert shares == {observed_share(par.cfg, par._state.world)}
    _, _, _, _, infos = par.step({a: par.action_space(a).sample() for a in par.agents})
    assert {info["coverage"] for info in infos.values()} == {observed_share(par.cfg, par._state.world)}


def test_gym_episode_ends_with_the_delayed_reward_or_the_lost_penalty() -> None:
    env = CmommtSingleRobotEnv(formulation=PAPER)
    cfg = env.cfg
    for seed in range(20):
        obs, info = env.reset(seed=seed)
        assert info["n_seen"] >= 1  # learning trials start with a target in view
        rewards = []
        steps = 0
        done = False
        while not done:
            obs, reward, done, truncated, info = env.step(env.action_space.sample())
            rewards.append(reward)
            steps += 1
            assert not truncated
        assert all(r == 0.0 for r in rewards[:-1])  # delayed reward
        if info["n_seen"] == 0:
            assert rewards[-1] == cfg.lost_reward
            np.testing.assert_allclose(obs[:4], cfg.mask_value)
        else:
            assert steps == cfg.learning_steps // cfg.action_steps
            assert rewards[-1] <= info["n_seen"]
            assert rewards[-1] in (info["n_seen"], info["n_seen"] - cfg.robot_in_view_penalty)
        with pytest.raises(RuntimeError, match="terminated"):
            env.step(np.int64(0))


def test_pettingzoo_robots_start_near_a_target_and_lost_robots_leave_motionless() -> None:
    env = CmommtParallelEnv(formulation=PAPER)
    cfg = env.cfg
    _, infos = env.reset(seed=1)
    for k, agent in enumerate(env.agents):
        env.action_space(agent).seed(k)  # the same random actions every run
    assert all(info["n_seen"] >= 1 for info in infos.values())
    total_steps = 0
    left: dict[str, np.ndarray] = {}
    while env.agents:
        obs, rewards, terms, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        total_steps += 1
        for agent, done in terms.items():
            if done and infos[agent]["n_seen"] == 0:
                assert rewards[agent] == cfg.lost_reward
                np.testing.assert_array_equal(obs[agent][:4], cfg.mask_value)
                left[agent] = env._state.world.robot_pos[0, env._index[agent]].copy()
            elif not done:
                assert rewards[agent] == 0.0
        for agent, pos in left.items():
            # Motionless up to the rounding of the projection onto the disk, for a robot that stopped at the wall.
            np.testing.assert_allclose(env._state.world.robot_pos[0, env._index[agent]], pos, rtol=0, atol=1e-9)
    assert left  # with random actions some robot loses its targets within the trial
    assert total_steps <= cfg.learning_steps // cfg.action_steps


@pytest.mark.parametrize("formulation", [PAPER, default_formulation()], ids=["paper", "default"])
@pytest.mark.parametrize("seed", range(4))
def test_the_gymnasium_env_replays_the_slice_for_the_same_seed(seed: int, formulation: Formulation) -> None:
    cfg = scenario()
    batch = ExperienceSlice(cfg, SliceConfig(formulation, n_arenas=1, learning_robots=(0,)), seed=seed).run_trial()
    # Robot 0 learns, the others explore: the slice with learning_robots=(0,).
    env = CmommtSingleRobotEnv(formulation=formulation)
    obs, _ = env.reset(seed=seed)
    for k in range(len(batch)):
        np.testing.assert_array_equal(obs, batch.state[k])
        obs, reward, terminated, _, _ = env.step(np.int64(batch.action[k]))
        np.testing.assert_array_equal(obs, batch.next_state[k])
        assert (reward, terminated) == (batch.reward[k], batch.done[k])
    assert terminated


def greedy_agent(cfg: ScenarioConfig) -> TabularAgent:
    """A fixed option-2 policy on random cells: greedy acting draws no random numbers, so the streams stay aligned."""
    rng = np.random.default_rng(42)
    disc = Discretization.from_per_action([rng.uniform(-150.0, 150.0, (4, 6)) for _ in range(8)])
    tables = rng.normal(0.0, 1.0, (cfg.n_robots, disc.size)).astype(np.float32)
    policy = Policy(PAPER, disc, tables, np.arange(cfg.n_robots))
    return TabularAgent(policy, Phase2Config(epsilon=0.0))


@pytest.mark.parametrize("seed", range(3))
def test_the_pettingzoo_env_replays_the_slice_for_the_same_seed(seed: int) -> None:
    cfg = scenario()
    agent = greedy_agent(cfg)
    batch = ExperienceSlice(cfg, SliceConfig(PAPER, n_arenas=1), seed=seed).run_trial(agent)
    env = CmommtParallelEnv(formulation=PAPER)  # every robot learns: the slice with learning_robots=None
    obs, _ = env.reset(seed=seed)
    rows: list[tuple[int, np.ndarray, int, float, np.ndarray, bool]] = []
    while env.agents:
        robots = np.array([env._index[a] for a in env.agents])
        states = np.stack([obs[a] for a in env.agents])
        actions = agent.act(robots, agent.cells(states), np.random.default_rng(), explore=False)
        obs, rewards, terms, _, _ = env.step(dict(zip(env.agents, actions, strict=True)))
        for a, i, s, act in zip(obs, robots, states, actions, strict=True):
            rows.append((int(i), s, int(act), rewards[a], obs[a], terms[a]))
    assert len(rows) == len(batch)
    for i in range(cfg.n_robots):
        mine = [row for row in rows if row[0] == i]
        sel = batch.robot == i
        np.testing.assert_array_equal(np.stack([row[1] for row in mine]), batch.state[sel])
        np.testing.assert_array_equal([row[2] for row in mine], batch.action[sel])
        np.testing.assert_array_equal(np.array([row[3] for row in mine], np.float32), batch.reward[sel])
        np.testing.assert_array_equal(np.stack([row[4] for row in mine]), batch.next_state[sel])
        np.testing.assert_array_equal([row[5] for row in mine], batch.done[sel])


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Tiny networks on 2 shared cores: torch's worker threads measured 4x slower than one thread."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.mark.usefixtures("one_torch_thread")
def test_stable_baselines3_dqn_learns_and_acts_on_the_registered_env() -> None:
    from stable_baselines3 import DQN

    env = gymnasium.make("cmommt/SingleRobot-v1", formulation=PAPER)
    cfg = env.unwrapped.cfg
    model = DQN(
        "MlpPolicy",
        env,
        learning_starts=200,
        buffer_size=2000,
        train_freq=8,
        target_update_interval=200,
        policy_kwargs={"net_arch": [32, 32]},
        seed=0,
        device="cpu",
    )
    initial = [p.detach().clone() for p in model.q_net.parameters()]
    model.learn(total_timesteps=1000)
    assert any(not (p == q).all() for p, q in zip(model.q_net.parameters(), initial, strict=True))  # it trained
    buffer = model.replay_buffer
    assert model.num_timesteps == 1000 and buffer.size() == 1000
    actions, rewards, dones = buffer.actions[:1000, 0, 0], buffer.rewards[:1000, 0], buffer.dones[:1000, 0]
    assert ((actions >= 0) & (actions < 8)).all()
    assert np.abs(buffer.observations[:1000]).max() <= cfg.mask_value
    assert dones.sum() >= 1000 // (cfg.learning_steps // cfg.action_steps)  # episodes last at most 20 env steps
    assert (rewards[dones == 0] == 0.0).all()  # the reward is delayed to the end of the episode
    obs, _ = env.reset(seed=1)
    steps, done = 0, False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        assert env.action_space.contains(action)
        obs, _, terminated, truncated, _ = env.step(action)
        done = terminated or truncated
        steps += 1
    assert 1 <= steps <= cfg.learning_steps // cfg.action_steps
