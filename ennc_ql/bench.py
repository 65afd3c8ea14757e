"""Benchmarks: commands that measure and report figures (tests never assert timings).

Usage::

    from ennc_ql.bench import bench_sim
    figures = bench_sim(seconds=2.0)
    figures["robot_steps_per_s"]["random"]
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from sim import HAND_MADE, ScenarioConfig, reset, scenario, sense, step, trial_reward

log = logging.getLogger(__name__)

SIM_TARGETS = {"random": 10e6, "a_cmommt": 3e6}
"""Robot-steps per second the simulator must reach on the 2-core reference machine (issue 2)."""


def _sim_rate(cfg: ScenarioConfig, controller_name: str, arenas: int, seconds: float) -> float:
    """Robot-steps/s of controller + physics + 6-D featurization + reward, for ``arenas`` arenas."""
    controller = HAND_MADE[controller_name]
    rng = np.random.default_rng(0)
    world = reset(cfg, arenas, rng)
    memory = controller.init(cfg, world, rng)
    obs = sense(cfg, world, rng)
    steps = 0
    start = time.perf_counter()
    deadline = start + seconds
    while True:
        velocity, memory = controller.act(cfg, world, obs, memory, rng)
        world = step(cfg, world, velocity, rng)
        obs = sense(cfg, world, rng)
        trial_reward(cfg, obs, "collab6d")
        steps += 1
        now = time.perf_counter()
        if now >= deadline:
            return steps * arenas * cfg.n_robots / (now - start)


def bench_sim(
    scenario_name: str = "cmommt-v1",
    batch_sizes: tuple[int, ...] = (256, 1024, 4096, 16384),
    seconds: float = 1.5,
) -> dict[str, Any]:
    """Best robot-steps/s over ``batch_sizes`` for the random controller and A-CMOMMT.

    A robot-step is one robot advanced one simulation step with its 6-D features and collaborative reward
    computed. Every kernel runs on one thread (see :mod:`sim._kernels`).
    """
    cfg = scenario(scenario_name)
    for name in ("random", "a-cmommt"):
        _sim_rate(cfg, name, 8, 0.05)  # compile (or load the numba cache) outside the measurement
    by_size: dict[str, dict[int, float]] = {"random": {}, "a_cmommt": {}}
    for arenas in batch_sizes:
        for name in ("random", "a-cmommt"):
            rate = _sim_rate(cfg, name, arenas, seconds)
            by_size[name.replace("-", "_")][arenas] = rate
            log.info("bench sim: %s, %d arenas: %.2f M robot-steps/s", name, arenas, rate / 1e6)
    best = {key: max(rates, key=rates.__getitem__) for key, rates in by_size.items()}
    return {
        "benchmark": "sim",
        "scenario": cfg.name,
        "robot_steps_per_s": {key: round(by_size[key][best[key]]) for key in by_size},
        "arenas": best["random"],
        "arenas_by_controller": best,
        "robots": cfg.n_robots,
        "targets": cfg.n_targets,
        "threads": 1,
        "by_batch_size": {key: {str(k): round(v) for k, v in rates.items()} for key, rates in by_size.items()},
        "target": SIM_TARGETS,
        "meets_target": {key: by_size[key][best[key]] >= SIM_TARGETS[key] for key in by_size},
    }
