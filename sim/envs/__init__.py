"""Gymnasium and PettingZoo adapters of the learning trial (optional extra ``ennc-ql[envs]``), converting at the edge.

Both wrap :mod:`sim.trial`, so they follow the rules of the experience slice: learners start within sensing range
of a target; one env step is one action of the formulation's action set held for ``action_steps`` simulation steps;
the formulation (``formulation=``, a :class:`sim.formulation.Formulation`; default: the run's,
:data:`sim.formulation.DEFAULT_FORMULATION`) names the state, the reward and the trial rules: under the paper's, a
trial-end reward is delayed to the end of the learning trial (``learning_steps`` simulation steps), and a robot that
loses every target gets ``lost_reward``, which ends its episode and leaves it motionless [paper; choice].
``info["coverage"]`` is the percentage of targets observed at that moment (the summand of metric A).

Importing this package registers the Gymnasium ids in :data:`GYM_IDS`, as Gymnasium environment packages do
(the adapters' modules are imported only when an env is made)::

    import gymnasium
    import sim.envs

    env = gymnasium.make("cmommt/SingleRobot-v1")               # robot 0 learns; the others explore
    env = gymnasium.make("sim.envs:cmommt/SingleRobot-v1")      # the same, importing this package on the way

    from sim.envs import pettingzoo_env
    aec, par = pettingzoo_env.env(), pettingzoo_env.parallel_env()   # every robot an agent
"""

from gymnasium.envs.registration import register

GYM_IDS = ("cmommt/SingleRobot-v1",)
"""Registered Gymnasium ids; keyword arguments of :class:`~sim.envs.gym_env.CmommtSingleRobotEnv` pass through
``gymnasium.make``, e.g. ``formulation=FORMULATIONS["paper"]`` or ``others="a-cmommt"``."""

register(id=GYM_IDS[0], entry_point="sim.envs.gym_env:CmommtSingleRobotEnv")
