"""Gymnasium and PettingZoo adapters (optional extra ``ennc-ql[envs]``), converting at the edge only.

Usage::

    from sim.envs.gym_env import CmommtSingleRobotEnv       # one learning robot; the others follow a controller
    from sim.envs.pettingzoo_env import CmommtParallelEnv   # every robot an agent

Both are constructible with no arguments (scenario ``cmommt-v1``, collaborative 6-D state). One env step is one
compass action held for ``action_steps`` simulation steps; the reward is delayed to the end of the learning trial
(``learning_steps`` simulation steps) or comes as ``lost_reward`` when a robot loses every target, which ends its
episode [paper; choice].
"""
