"""The CMOMMT world: a pure, vectorized simulator over a batch of arenas, its featurizers, rewards, metric A and
the hand-made controllers. Imports only numpy and numba; the Gymnasium / PettingZoo adapters live in
:mod:`sim.envs` so that this package stays free of them.
"""

from sim.config import SCENARIOS, ForceLawConfig, ScenarioConfig, scenario
from sim.controllers import COMPASS, HAND_MADE, N_ACTIONS, Controller, ForceController, RandomController
from sim.features import FEATURIZERS, coverage, featurize, lost, trial_reward
from sim.rollout import EvalResult, evaluate
from sim.world import Observation, WorldState, reset, sense, step

__all__ = [
    "COMPASS",
    "FEATURIZERS",
    "HAND_MADE",
    "N_ACTIONS",
    "SCENARIOS",
    "Controller",
    "EvalResult",
    "ForceController",
    "ForceLawConfig",
    "Observation",
    "RandomController",
    "ScenarioConfig",
    "WorldState",
    "coverage",
    "evaluate",
    "featurize",
    "lost",
    "reset",
    "scenario",
    "sense",
    "step",
    "trial_reward",
]
