"""Benchmarks: commands that measure and report figures (tests never assert timings).

Usage::

    from ennc_ql.bench import bench_sim
    figures = bench_sim(seconds=2.0)
    figures["robot_steps_per_s"]["random"]
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from algorithm.transitions import Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from ennc_ql.progress import ProgressBar
from monitor import Monitor, paths
from sim import HAND_MADE, N_ACTIONS, ScenarioConfig, reset, scenario, sense, step, trial_reward

SIM_TARGETS = {"random": 10e6, "a_cmommt": 3e6}
"""Robot-steps per second the simulator must reach on the 2-core reference machine (issue 2)."""
DRAW_EVERY = 10
"""Steps between arena drawings in ``bench sim``: as often as an actor draws (every step of one trial in ten)."""


def _sim_rate(
    cfg: ScenarioConfig, controller_name: str, arenas: int, seconds: float, monitor: Monitor | None = None
) -> float:
    """Robot-steps/s of controller + physics + 6-D featurization + reward, for ``arenas`` arenas.

    Arena 0 goes to ``monitor`` every ``DRAW_EVERY`` steps; the call is made even when monitoring is off, so the
    figure includes what the no-op monitor costs.
    """
    monitor = monitor or Monitor()
    origin = paths.actor_arena("bench")
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
            _sim_rate(cfg, name, 8, 0.05)  # compile (or load the numba cache) outside the measurement
        for arenas in batch_sizes:
            for name in controllers:
                bar.show(status=f"{name}, {arenas} arenas, {seconds:g} s")
                rate = _sim_rate(cfg, name, arenas, seconds, monitor)
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


def cmommt_experience(tuples: int, seed: int = 0, action: int | None = None) -> Transitions:
    """``tuples`` collaborative (6-D) tuples from random-exploration learning trials (only ``action``'s, if given)."""
    cfg = scenario()
    explorer = ExperienceSlice(cfg, SliceConfig(n_arenas=1000, featurizer="collab6d"), seed)
    parts: list[Transitions] = []
    collected = 0
    while collected < tuples:
        batch = explorer.run_trial()
        if action is not None:
            batch = batch.take(np.nonzero(batch.action == action)[0])
        parts.append(batch)
        collected += len(batch)
    data = Transitions.concat(parts)
    return data.take(np.arange(tuples))


def bench_ennc(
    patterns: int = 100_000,
    cycles: int = 250,
    phase1_tuples: int = 1_000_000,
    seed: int = 0,
) -> dict[str, Any]:
    """ENNC fit time against scikit-learn's k-means on the same data, and ENNC-QL phase 1 on many tuples.

    The patterns are standardized collaborative states of one action (East) from random exploration with their
    first-iteration Q-target classes, exactly what phase 1 trains one classifier on. k-means gets k = ENNC's final
    prototype count, 250 Lloyd iterations and one init; it is the reference for "not much more work on the data
    than a Lloyd iteration".
    """
    from sklearn.cluster import KMeans

    from algorithm.ennc import ENNC
    from algorithm.phase1 import Phase1Config, phase1, standard_scale, to_classes

    phase1_figures: dict[str, Any] = {}
    with ProgressBar("bench ennc", total=5 if phase1_tuples else 3, unit="phases") as bar:
        bar.show(status=f"exploring for {patterns:,} patterns")
        sample = cmommt_experience(patterns, seed, action=2)
        x = sample.state / standard_scale(sample.state)
        y = to_classes(np.where(sample.done, sample.reward, 0.0), Phase1Config())
        bar.mark(f"{len(x):,} patterns, {np.unique(y).size} classes", n=1)
        bar.show(status=f"ENNC, {cycles} cycles")
        start = time.perf_counter()
        model = ENNC(n_cycles=cycles, random_state=seed).fit(x, y)
        ennc_seconds = time.perf_counter() - start
        bar.mark(f"ENNC {ennc_seconds:.2f} s, {model.n_prototypes_} prototypes", n=2)
        bar.show(status=f"k-means, k = {model.n_prototypes_}")
        kmeans = KMeans(n_clusters=model.n_prototypes_, max_iter=cycles, n_init=1, tol=0.0, random_state=seed)
        start = time.perf_counter()
        kmeans.fit(x)
        kmeans_seconds = time.perf_counter() - start
        bar.mark(f"k-means {kmeans_seconds:.2f} s ({kmeans.n_iter_} iterations)", n=3)
        if phase1_tuples:
            bar.show(status=f"exploring for {phase1_tuples:,} phase-1 tuples")
            big = cmommt_experience(phase1_tuples, seed)
            bar.mark(f"{len(big):,} phase-1 tuples", n=4)
            bar.show(status="phase 1, one iteration")
            start = time.perf_counter()
            result = phase1(big, N_ACTIONS, Phase1Config(max_iterations=1, n_cycles=cycles), seed=seed)
            phase1_figures = {
                "phase1_tuples": phase1_tuples,
                "phase1_seconds": round(time.perf_counter() - start, 3),
                "phase1_prototypes_per_action": [int(s) for s in result.discretization.sizes()],
            }
            bar.mark(f"phase 1 on {phase1_tuples:,} tuples: {phase1_figures['phase1_seconds']:.1f} s", n=5)
    out: dict[str, Any] = {
        "benchmark": "ennc",
        "patterns": len(x),
        "dims": int(x.shape[1]),
        "cycles": cycles,
        "classes": int(np.unique(y).size),
        "n_prototypes": int(model.n_prototypes_),
        "accuracy": round(float(model.score(x, y)), 4),
        "ennc_seconds": round(ennc_seconds, 3),
        "kmeans_seconds": round(kmeans_seconds, 3),
        "kmeans_iterations": int(kmeans.n_iter_),
        "ratio": round(ennc_seconds / kmeans_seconds, 3),
        "target": {"ratio": 2.0, "phase1_seconds": 60.0},
        "torch_threads": torch.get_num_threads(),
    }
    out.update(phase1_figures)
    out["meets_target"] = {
        "ratio": out["ratio"] <= 2.0,
        "phase1_seconds": out.get("phase1_seconds", np.inf) <= 60.0,
    }
    return out
