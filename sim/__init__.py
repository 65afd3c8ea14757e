"""The CMOMMT world: a pure, vectorized simulator over a batch of arenas, its featurizers, rewards and action sets
and the formulation built of them (:mod:`sim.formulation`), metric A, the hand-made controllers and the
learning-trial rules (:mod:`sim.trial`). Imports only numpy and numba; the
Gymnasium / PettingZoo adapters live in :mod:`sim.envs` so that this package stays free of them.
"""

from sim.config import SCENARIOS, ForceLawConfig, ScenarioConfig, scenario
from sim.controllers import (
    COMPASS,
    CONTROLLERS,
    HAND_MADE,
    N_ACTIONS,
    ORACLES,
    Controller,
    ForceController,
    RandomController,
)
from sim.features import FEATURIZERS, coverage, featurize, lost, trial_reward
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS, Formulation, TrialRules
from sim.rollout import EvalResult, evaluate
from sim.trial import TrialState, TrialStep, explore_actions, random_actions, reset_trial, step_trial
from sim.world import Observation, WorldState, reset, sense, step

__all__ = [
    "COMPASS",
    "CONTROLLERS",
    "DEFAULT_FORMULATION",
    "FEATURIZERS",
    "FORMULATIONS",
    "HAND_MADE",
    "N_ACTIONS",
    "ORACLES",
    "SCENARIOS",
    "Controller",
    "EvalResult",
    "ForceController",
    "ForceLawConfig",
    "Formulation",
    "Observation",
    "RandomController",
    "ScenarioConfig",
    "TrialRules",
    "TrialState",
    "TrialStep",
    "WorldState",
    "coverage",
    "evaluate",
    "explore_actions",
    "featurize",
    "lost",
    "random_actions",
    "reset",
    "reset_trial",
    "scenario",
    "sense",
    "step",
    "step_trial",
    "trial_reward",
]
