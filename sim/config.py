"""Scenario parameters of the CMOMMT world.

Every value carries its provenance from ``shared/spec/algorithms.md``: [paper] is stated in Fernández, Borrajo &
Parker; [public] comes from public A-CMOMMT re-implementations; [choice] is this project's reconstruction where no
source gives a value. ``cmommt-v1`` is calibrated so that A-CMOMMT observes about 70% of the targets, as in the paper.

Usage::

    from sim.config import scenario
    cfg = scenario("cmommt-v1")
    cfg = scenario("cmommt-v1", sensor_noise_std=5.0)   # a variant; unknown fields raise TypeError
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

LocalTarget = Literal["furthest", "nearest"]


@dataclass(frozen=True, slots=True)
class ForceLawConfig:
    """Distances of the A-CMOMMT force law [paper: attraction to targets, repulsion from robots; shape: public].

    ``f_target(d)`` is -1 + d/do1 up to do1, rises to 1 at do2, stays 1 up to do3 (= sensing range), and falls to
    0 at do4 (the predictive tracking range: beyond sensing, a robot knows only its own predicted sightings and its
    teammates' reports). ``g_robot(d)`` is -1 up to dr1 and rises to 0 at dr2. Defaults are the public
    code's values scaled to this arena [public]; each hand-made controller holds its own (``sim.controllers``).
    """

    do1: float = 20.0
    do2: float = 40.0
    do3: float = 150.0
    do4: float = 180.0
    dr1: float = 62.5
    dr2: float = 100.0
    shared_target_weight: float = 0.25
    """Weight of a target that another robot already observes [public]; the local controller uses 1."""
    predict_steps: int = 60
    """Steps a robot predicts a target forward (linearly, from its last observed position and velocity) after
    losing sight of it; such a prediction in (do3, do4] attracts it [Parker 2002: do4 is the predictive tracking
    range; the horizon is a choice]."""
    reported_weight: float = 0.0
    """Weight, in the (do3, do4] band, of a target another robot reports seeing now; 0 ignores reports there
    [choice: measured below own predictions alone, docs/notebook.md, "2026-12-02: the honest A-CMOMMT, tuned on
    training trials"]."""

    def __post_init__(self) -> None:
        if not 0.0 < self.do1 < self.do2 <= self.do3 < self.do4:
            raise ValueError(f"force law needs 0 < do1 < do2 <= do3 < do4, got {self}")
        if not 0.0 <= self.dr1 < self.dr2:
            raise ValueError(f"force law needs 0 <= dr1 < dr2, got {self}")
        if not 0.0 <= self.shared_target_weight <= 1.0:
            raise ValueError("shared_target_weight must lie in [0, 1]")
        if not 0.0 <= self.reported_weight <= 1.0:
            raise ValueError("reported_weight must lie in [0, 1]")
        if self.predict_steps < 0:
            raise ValueError("predict_steps must be non-negative")


@dataclass(frozen=True, slots=True)
class ScenarioConfig:
    """One CMOMMT scenario; all lengths in arena units, all times in simulation steps."""

    name: str = "cmommt-v1"
    """The scenario's versioned name (``sim.SCENARIOS``), as a policy file's header and the wire carry it."""
    arena_radius: float = 1000.0
    """Radius R of the disk-shaped arena centred at the origin [choice]."""
    n_robots: int = 10
    """m [paper]."""
    n_targets: int = 10
    """n [paper]."""
    sensing_range: float = 150.0
    """r_s, 360° sensors [choice: every real distance vector stays inside the (1000, 1000) mask, paper]."""
    robot_speed: float = 7.5
    """Holonomic robots move at most this far per step; they are projected back onto the disk [choice]."""
    target_speed_frac: float = 0.75
    """Each target's fixed speed is uniform in [0, target_speed_frac * robot_speed] [choice]."""
    target_turn_prob: float = 0.05
    """Per step, a target draws a new uniform heading with this probability [choice]."""
    sensor_noise_std: float = 0.0
    """Std of Gaussian noise on observed relative positions; 0 = noiseless [choice; the paper's sensors are noisy]."""
    mask_value: float = 1000.0
    """Both components of a feature pair when nothing is in view [paper]."""
    action_steps: int = 5
    """Simulation steps one discrete action lasts [choice; the paper fixes but does not give it]."""
    test_steps: int = 1000
    """Length of a test trial [paper]."""
    test_trials: int = 10
    """Seeded test trials averaged per evaluation [paper]."""
    learning_steps: int = 100
    """Length of a learning trial [paper]."""
    lost_reward: float = -1.0
    """Reward when a robot loses all targets [paper: negative; value: choice]. Whether that ends its learning trial is
    one of the formulation's trial rules (:class:`sim.formulation.TrialRules`)."""
    robot_in_view_penalty: float = 2.0
    """k(T) in the collaborative reward r_i(T) = Σ_j b_ij(T) − k(T) [paper Eq. 2]."""
    redundancy_penalty: float = 0.5
    """What the ``difference-redundancy`` reward takes from a robot for a step in which it sees targets, but only
    ones a teammate sees too [choice]."""
    redundancy_potential: float = 2.0
    """k of the ``difference-shaped`` reward's potential Φ = −k (1 − d / sensing_range) for a robot seeing only
    teammate-watched targets, d the nearest one's distance (0 otherwise) [choice]."""
    recall_steps: int = 120
    """How long a robot of a remembering state (``frame11d-recall``, :mod:`sim.recall`) keeps a target it lost as
    its remembered target, in steps [choice: the tuned A-CMOMMT's prediction horizon when the state was made, 120
    steps; the law's finer grid of 2026-12-06 chose 240 for the law, and the state keeps its own, which every policy
    file of this state was learned with]."""
    local_target: LocalTarget = "furthest"
    """Target the 2-D local state points at [paper: furthest; once 'nearest']."""

    def __post_init__(self) -> None:
        positive = ("arena_radius", "sensing_range", "robot_speed", "mask_value", "robot_in_view_penalty")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        for name in (
            "n_robots",
            "n_targets",
            "action_steps",
            "test_steps",
            "test_trials",
            "learning_steps",
            "recall_steps",
        ):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)!r}")
        if not self.target_speed_frac >= 0.0:
            raise ValueError("target_speed_frac must be non-negative")
        if not 0.0 <= self.target_turn_prob <= 1.0:
            raise ValueError("target_turn_prob must lie in [0, 1]")
        if self.sensor_noise_std < 0:
            raise ValueError("sensor_noise_std must be non-negative")
        for name in ("redundancy_penalty", "redundancy_potential"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
        if self.mask_value <= self.sensing_range:
            raise ValueError("mask_value must exceed sensing_range so a masked feature cannot look like a real one")
        if self.local_target not in ("furthest", "nearest"):
            raise ValueError(f"local_target must be 'furthest' or 'nearest', got {self.local_target!r}")

    def replace(self, **changes: object) -> ScenarioConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]


SCENARIOS: dict[str, ScenarioConfig] = {"cmommt-v1": ScenarioConfig()}


def scenario(name: str = "cmommt-v1", **overrides: object) -> ScenarioConfig:
    """The named scenario, optionally with some fields overridden."""
    try:
        base = SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(sorted(SCENARIOS))}") from None
    return base.replace(**overrides) if overrides else base
