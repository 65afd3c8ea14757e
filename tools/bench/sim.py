"""``ennc-ql bench sim``: robot-steps per second of the simulator (controller, physics, 6-D featurization and the
collaborative reward), at the best of several batch sizes::

    figures = bench_sim(seconds=2.0)
    figures["robot_steps_per_s"]["random"]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from monitor import Monitor, paths
from sim import CONTROLLERS, ScenarioConfig, reset, scenario, sense, step, trial_reward
from sim.features import REWARDS
from tools.progress import ProgressBar

PAPER_REWARD = REWARDS["eq2"]
"""The reward the loop pays, the paper's Eq. 2, so that the rate includes a reward's cost."""

SIM_TARGETS = {"random": 10e6, "a_cmommt": 3e6}
"""Robot-steps per second the simulator must reach on the 2-core reference machine (issue 2)."""
DRAW_EVERY = 10
"""Steps between arena drawings in ``bench sim``: as often as an actor draws (every step of one trial in ten)."""


def sim_rate(
    cfg: ScenarioConfig, controller_name: str, arenas: int, seconds: float, monitor: Monitor | None = None
) -> float:
    """Robot-steps/s of controller + physics + 6-D featurization + reward, for ``arenas`` arenas.

    Arena 0 goes to ``monitor`` every ``DRAW_EVERY`` steps; the call is made even when monitoring is off, so the
    figure includes what the no-op monitor costs.
    """
    monitor = monitor or Monitor()
    origin = paths.actor_arena("bench")
    controller = CONTROLLERS[controller_name]
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
        trial_reward(cfg, obs, PAPER_REWARD)
        steps += 1
        if steps % DRAW_EVERY == 0:
            monitor.arena(
                origin,
                world.robot_pos[0],
                world.target_pos[0],
                sensing_range=cfg.sensing_range,
                arena_radius=cfg.arena_radius,
                sim_step=steps,
            )
        now = time.perf_counter()
        if now >= deadline:
            return steps * arenas * cfg.n_robots / (now - start)


def bench_sim(
    scenario_name: str = "cmommt-v1",
    batch_sizes: tuple[int, ...] = (256, 1024, 4096, 16384),
    seconds: float = 1.5,
    monitor: Monitor | None = None,
) -> dict[str, Any]:
    """Best robot-steps/s over ``batch_sizes`` for the random controller and A-CMOMMT.

    A robot-step is one robot advanced one simulation step with its 6-D features and collaborative reward
    computed. Every kernel runs on one thread (see :mod:`sim._kernels`).
    """
    cfg = scenario(scenario_name)
    controllers = ("random", "a-cmommt")
    by_size: dict[str, dict[int, float]] = {"random": {}, "a_cmommt": {}}
    with ProgressBar("bench sim", total=len(batch_sizes) * len(controllers), unit="runs") as bar:
        bar.show(status="compiling the kernels (or loading numba's cache)")
        for name in controllers:
            sim_rate(cfg, name, 8, 0.05)  # compile (or load the numba cache) outside the measurement
        for arenas in batch_sizes:
            for name in controllers:
                bar.show(status=f"{name}, {arenas} arenas, {seconds:g} s")
                rate = sim_rate(cfg, name, arenas, seconds, monitor)
                by_size[name.replace("-", "_")][arenas] = rate
                bar.mark(f"{name}, {arenas} arenas: {rate / 1e6:.2f} M robot-steps/s", n=bar.n + 1)
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
        "monitoring": monitor is not None and monitor.enabled,
        "by_batch_size": {key: {str(k): round(v) for k, v in rates.items()} for key, rates in by_size.items()},
        "target": SIM_TARGETS,
        "meets_target": {key: by_size[key][best[key]] >= SIM_TARGETS[key] for key in by_size},
    }


def sim_table(out: dict[str, Any]) -> str:
    """The lines ``ennc-ql bench sim`` prints without ``--json``."""
    rates = out["robot_steps_per_s"]
    return "\n".join(
        f"{name:>9}: {rates[name] / 1e6:6.2f} M robot-steps/s at {out['arenas_by_controller'][name]} arenas "
        f"(target {out['target'][name] / 1e6:.0f} M: {'met' if out['meets_target'][name] else 'NOT met'})"
        for name in rates
    )
