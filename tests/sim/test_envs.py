"""The Gymnasium and PettingZoo adapters pass the official checkers and follow the trial rules."""

from __future__ import annotations

import numpy as np
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test

from sim.envs.gym_env import CmommtSingleRobotEnv
from sim.envs.pettingzoo_env import CmommtParallelEnv


def test_gymnasium_env_passes_the_checker() -> None:
    check_env(CmommtSingleRobotEnv(), skip_render_check=True)
    check_env(CmommtSingleRobotEnv(featurizer="local2d", others="a-cmommt"), skip_render_check=True)


def test_pettingzoo_env_passes_the_api_and_seed_tests() -> None:
    parallel_api_test(CmommtParallelEnv(), num_cycles=300)
    parallel_seed_test(CmommtParallelEnv)


def test_gym_episode_ends_with_the_delayed_reward_or_the_lost_penalty() -> None:
    env = CmommtSingleRobotEnv()
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


def test_pettingzoo_lost_robots_leave_and_the_rest_finish_the_trial() -> None:
    env = CmommtParallelEnv()
    cfg = env.cfg
    env.reset(seed=1)
    total_steps = 0
    while env.agents:
        _, rewards, terms, _, infos = env.step({a: env.action_space(a).sample() for a in env.agents})
        total_steps += 1
        for agent, done in terms.items():
            if done and infos[agent]["n_seen"] == 0:
                assert rewards[agent] == cfg.lost_reward
            elif not done:
                assert rewards[agent] == 0.0
    assert total_steps <= cfg.learning_steps // cfg.action_steps
