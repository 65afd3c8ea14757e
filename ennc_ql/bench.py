"""Benchmarks: commands that measure and report figures (tests never assert timings).

Usage::

    from ennc_ql.bench import bench_actor, bench_sim
    figures = bench_sim(seconds=2.0)
    figures["robot_steps_per_s"]["random"]
    bench_actor(seconds=2.0)["ratio"]              # an actor's phase-2 slice / the bare simulator
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from algorithm.agent import Phase2Config, TabularAgent
from algorithm.policy import Policy
from algorithm.transitions import Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from algorithm.wire import experience_message
from ennc_ql.progress import ProgressBar
from monitor import Monitor, paths
from sim import HAND_MADE, N_ACTIONS, ScenarioConfig, reset, scenario, sense, step, trial_reward
from sim.features import FORMULATIONS

SIM_TARGETS = {"random": 10e6, "a_cmommt": 3e6}
"""Robot-steps per second the simulator must reach on the 2-core reference machine (issue 2)."""
ACTOR_TARGET_RATIO = 0.25
"""An actor's phase-2 slice must run at this fraction of the bare simulator's robot-steps/s (actor throughput issue)."""
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
        trial_reward(cfg, obs, "eq2")
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


REGION_SITES = 64
"""Voronoi sites of the region-shaped classes of :func:`region_patterns`."""
MASK_VALUE = 3.0
"""Value of the masked block in :func:`region_patterns`: like a masked CMOMMT feature after scaling, a constant far
outside the unit cube the unmasked values fill."""


def region_patterns(patterns: int, seed: int = 0, masked_share: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """6-D patterns in the unit cube whose class (0 or 1) is that of the Voronoi region of dims 0–1 they fall in.

    Shaped like CMOMMT states (6-D, a block of features masked to one constant: dims 4–5 for ``masked_share`` of
    the patterns), but with class boundaries that ENNC must tile with prototypes: the four unused dims spread
    every region, so the classifier grows thousands of prototypes (about one per three patterns at 5 000).
    """
    rng = np.random.default_rng(seed)
    x = rng.uniform(0.0, 1.0, (patterns, 6))
    sites = rng.uniform(0.0, 1.0, (REGION_SITES, 2))
    site_class = rng.integers(0, 2, REGION_SITES)
    nearest = np.empty(patterns, dtype=np.int64)
    for start in range(0, patterns, 65536):  # bounded memory for any size
        block = x[start : start + 65536, None, :2] - sites[None]
        nearest[start : start + 65536] = np.argmin((block * block).sum(axis=2), axis=1)
    x[rng.random(patterns) < masked_share, 4:] = MASK_VALUE
    return x, site_class[nearest]


def ennc_vs_kmeans(
    x: np.ndarray, y: np.ndarray, cycles: int, seed: int = 0, threads: int | None = None
) -> dict[str, Any]:
    """ENNC (``cycles`` cycles) and scikit-learn's k-means (k = ENNC's final prototype count, at most ``cycles``
    Lloyd iterations from k random patterns) on the same patterns; per-cycle and per-iteration seconds and their
    ratio.

    The ratio is per cycle because k-means may converge before ``cycles`` iterations; a Lloyd iteration is the
    reference for "not much more work on the data than a Lloyd iteration". ``threads`` (None: as set) bounds the
    threads of both, torch's and k-means' OpenMP/BLAS pools alike.
    """
    from sklearn.cluster import KMeans
    from threadpoolctl import threadpool_limits

    from algorithm.ennc import ENNC

    start = time.perf_counter()
    model = ENNC(n_cycles=cycles, random_state=seed, n_threads=threads).fit(x, y)
    ennc_seconds = time.perf_counter() - start
    # Random patterns as the initial centres: k-means++ seeding costs O(N·k·log k), which is no Lloyd iteration.
    centres = x[np.random.default_rng(seed).choice(len(x), model.n_prototypes_, replace=False)]
    kmeans = KMeans(n_clusters=model.n_prototypes_, init=centres, max_iter=cycles, n_init=1, tol=0.0)
    with threadpool_limits(threads):
        start = time.perf_counter()
        kmeans.fit(x)
    kmeans_seconds = time.perf_counter() - start
    per_cycle = ennc_seconds / max(1, cycles)
    per_iteration = kmeans_seconds / max(1, int(kmeans.n_iter_))
    return {
        "patterns": len(x),
        "dims": int(x.shape[1]),
        "cycles": cycles,
        "classes": int(np.unique(y).size),
        "n_prototypes": int(model.n_prototypes_),
        "accuracy": round(float(model.score(x, y)), 4),
        "ennc_seconds": round(ennc_seconds, 3),
        "ennc_seconds_per_cycle": round(per_cycle, 5),
        "kmeans_seconds": round(kmeans_seconds, 3),
        "kmeans_iterations": int(kmeans.n_iter_),
        "kmeans_seconds_per_iteration": round(per_iteration, 5),
        "ratio": round(per_cycle / per_iteration, 3),
    }


def bench_ennc(
    patterns: int = 100_000,
    cycles: int = 250,
    phase1_tuples: int = 1_000_000,
    seed: int = 0,
    region_size: int = 20_000,
    threads: int | None = None,
) -> dict[str, Any]:
    """ENNC against scikit-learn's k-means (:func:`ennc_vs_kmeans`) on CMOMMT states and on
    :func:`region_patterns`, and ENNC-QL phase 1 on many tuples.

    The CMOMMT patterns are standardized collaborative states of one action (East) from random exploration with
    their first-iteration Q-target classes, exactly what phase 1 trains one classifier on (a few hundred
    prototypes); their figures are the top-level keys. ``region_size`` patterns of :func:`region_patterns` (0
    skips them) make ENNC grow thousands of prototypes; their figures are under ``"regions"``. ``threads`` as in
    :func:`ennc_vs_kmeans` (1 gives steadier figures on busy shared cores).
    """
    from algorithm.phase1 import Phase1Config, phase1, standard_scale, to_classes

    out: dict[str, Any] = {"benchmark": "ennc"}
    total = 2 + (1 if region_size else 0) + (2 if phase1_tuples else 0)
    with ProgressBar("bench ennc", total=total, unit="phases") as bar:
        bar.show(status=f"exploring for {patterns:,} patterns")
        sample = cmommt_experience(patterns, seed, action=2)
        x = sample.state / standard_scale(sample.state)
        y = to_classes(np.where(sample.done, sample.reward, 0.0), Phase1Config())
        bar.mark(f"{len(x):,} patterns, {np.unique(y).size} classes", n=1)
        bar.show(status=f"CMOMMT: ENNC {cycles} cycles, then k-means")
        out.update(ennc_vs_kmeans(x, y, cycles, seed, threads))
        bar.mark(f"CMOMMT: {out['n_prototypes']} prototypes, ratio {out['ratio']:.2f}", n=2)
        if region_size:
            bar.show(status=f"regions: {region_size:,} patterns, ENNC {cycles} cycles, then k-means")
            out["regions"] = ennc_vs_kmeans(*region_patterns(region_size, seed), cycles, seed, threads)
            bar.mark(
                f"regions: {out['regions']['n_prototypes']} prototypes, ratio {out['regions']['ratio']:.2f}",
                n=bar.n + 1,
            )
        if phase1_tuples:
            bar.show(status=f"exploring for {phase1_tuples:,} phase-1 tuples")
            big = cmommt_experience(phase1_tuples, seed)
            bar.mark(f"{len(big):,} phase-1 tuples", n=bar.n + 1)
            bar.show(status="phase 1, one iteration")
            start = time.perf_counter()
            result = phase1(big, N_ACTIONS, Phase1Config(max_iterations=1, n_cycles=cycles), seed=seed)
            out["phase1_tuples"] = phase1_tuples
            out["phase1_seconds"] = round(time.perf_counter() - start, 3)
            out["phase1_prototypes_per_action"] = [int(s) for s in result.discretization.sizes()]
            bar.mark(f"phase 1 on {phase1_tuples:,} tuples: {out['phase1_seconds']:.1f} s", n=bar.n + 1)
    out["target"] = {"ratio": 2.0, "phase1_seconds": 60.0}
    out["torch_threads"] = threads or torch.get_num_threads()
    out["meets_target"] = {
        "ratio": out["ratio"] <= 2.0 and out.get("regions", out)["ratio"] <= 2.0,
        "phase1_seconds": out.get("phase1_seconds", np.inf) <= 60.0,
    }
    return out


def bench_phase1(store_sizes: tuple[int, ...] = (100_000, 300_000, 1_000_000), seed: int = 0) -> dict[str, Any]:
    """Phase 1 as the learner runs it (its default ``Phase1Config``) on stores of each size of random-exploration
    tuples: seconds of the fit and prototypes per action. The learner fits ENNC on at most ``max_patterns`` tuples
    per action but computes the Q targets on all of them, so the time grows with the store more slowly than it."""
    from algorithm.phase1 import phase1
    from learner.config import LearnerConfig

    config = LearnerConfig().phase1
    rows = []
    with ProgressBar("bench phase1", total=len(store_sizes) + 1, unit="steps") as bar:
        bar.show(status=f"exploring for {max(store_sizes):,} tuples")
        data = cmommt_experience(max(store_sizes), seed)
        bar.mark(f"{len(data):,} tuples", n=1)
        for size in store_sizes:
            bar.show(status=f"phase 1 on {size:,} tuples")
            # The newest tuples of a store of this size (the store keeps the newest).
            store = data.take(np.arange(len(data) - size, len(data)))
            start = time.perf_counter()
            result = phase1(store, N_ACTIONS, config, seed=seed)
            seconds = time.perf_counter() - start
            sizes = [int(s) for s in result.discretization.sizes()]
            rows.append({"store_tuples": size, "seconds": round(seconds, 2), "prototypes_per_action": sizes})
            bar.mark(f"{size:,} tuples: {seconds:.1f} s", n=bar.n + 1)
    return {"max_patterns": config.max_patterns, "max_iterations": config.max_iterations, "rows": rows}


def phase1_table(out: dict[str, Any]) -> str:
    head = (
        f"phase 1 as the learner runs it (at most {out['max_patterns']:,} tuples per action fitted, "
        f"{out['max_iterations']} iteration)"
    )
    lines = [
        f"  {r['store_tuples']:>9,} tuples: {r['seconds']:7.2f} s, "
        f"{sum(r['prototypes_per_action']) / len(r['prototypes_per_action']):.0f} prototypes per action"
        for r in out["rows"]
    ]
    return "\n".join([head, *lines])


def _ennc_row(name: str, f: dict[str, Any]) -> str:
    return (
        f"{name:>7}: {f['patterns']} x {f['dims']}, {f['n_prototypes']} prototypes, ENNC {f['ennc_seconds']:.2f} s "
        f"({f['ennc_seconds_per_cycle'] * 1e3:.2f} ms/cycle), k-means {f['kmeans_seconds']:.2f} s "
        f"({f['kmeans_iterations']} it, {f['kmeans_seconds_per_iteration'] * 1e3:.2f} ms/it), ratio {f['ratio']:.2f}"
    )


def ennc_table(out: dict[str, Any]) -> str:
    rows = [_ennc_row("CMOMMT", out)] + ([_ennc_row("regions", out["regions"])] if "regions" in out else [])
    met = "met" if out["meets_target"]["ratio"] else "NOT met"
    table = "\n".join(rows) + f"\nENNC cycle / Lloyd iteration at equal k: target <= 2 ({met})"
    if "phase1_seconds" in out:
        met = "met" if out["meets_target"]["phase1_seconds"] else "NOT met"
        table += (
            f"\nENNC-QL phase 1 on {out['phase1_tuples']} tuples: {out['phase1_seconds']:.1f} s (target <= 60 s: {met})"
        )
    return table


def bench_policy(cfg: ScenarioConfig, arenas: int = 500, explore_trials: int = 2, seed: int = 0) -> Policy:
    """A realistic phase-2 policy: ENNC-QL phase 1 (option 2, the learner's defaults) on random-exploration tuples.

    Two trials in 500 arenas give ≈ 180 k tuples and ≈ 150–300 prototypes per action, the size a ``make run``
    policy has (see the README), so the nearest-prototype search costs what it costs in a real run.
    """
    from algorithm.phase1 import Phase1Config, phase1

    explorer = ExperienceSlice(cfg, SliceConfig(n_arenas=arenas, featurizer="collab6d"), seed)
    data = Transitions.concat([explorer.run_trial() for _ in range(explore_trials)])
    disc = phase1(data, N_ACTIONS, Phase1Config(max_iterations=1, max_patterns=30_000), seed=seed).discretization
    return Policy(
        featurizer="collab6d",
        discretization=disc,
        tables=np.tile(disc.labels, (cfg.n_robots, 1)),
        robot_table=np.arange(cfg.n_robots),
        action_steps=cfg.action_steps,
        method="ennc-ql-collab-option2",
    )


def _actor_trials(
    cfg: ScenarioConfig, agent: TabularAgent, arenas: int, seconds: float, batch_size: int, seed: int
) -> dict[str, float]:
    """Phase-2 learning trials as an actor runs them (every robot learns), with its experience messages built.

    Returns the robot-steps, tuples and the seconds spent in the slice and in building the messages.
    """
    sl = ExperienceSlice(cfg, SliceConfig(n_arenas=arenas, featurizer="collab6d"), seed)
    steps = tuples = 0
    slice_s = message_s = 0.0
    while steps == 0 or slice_s + message_s < seconds:
        start = time.perf_counter()
        batch = sl.run_trial(agent, learn=True)
        built = time.perf_counter()
        for seq, first in enumerate(range(0, len(batch), batch_size)):
            part = batch.take(np.arange(first, min(first + batch_size, len(batch))))
            experience_message(
                part, actor_id="bench", incarnation=1, seq=seq, policy_version=1, formulation=FORMULATIONS["paper"]
            )
        message_s += time.perf_counter() - built
        slice_s += built - start
        steps += arenas * cfg.n_robots * cfg.learning_steps
        tuples += len(batch)
    return {"steps": steps, "tuples": tuples, "slice_s": slice_s, "message_s": message_s}


def bench_actor(
    scenario_name: str = "cmommt-v1",
    arenas: int = 500,
    seconds: float = 1.5,
    rounds: int = 3,
    policy: Policy | None = None,
    batch_size: int = 16384,
) -> dict[str, Any]:
    """An actor's phase-2 slice against the bare simulator, measured in the same run.

    ``rounds`` alternations of ``seconds`` of the simulator (random controller, the same ``arenas``) and of at least
    ``seconds`` (whole trials) of the actor's learning trials (ε-greedy on per-robot tables, on-line Eq. 1,
    experience messages built as the actor builds them), so that a machine whose load changes meanwhile slows both
    alike. ``policy`` None learns a realistic one (:func:`bench_policy`).
    """
    cfg = scenario(scenario_name)
    with ProgressBar("bench actor", total=2 * rounds + 1, unit="phases") as bar:
        bar.show(status="learning a policy (exploration + phase 1)" if policy is None else "policy given")
        policy = policy or bench_policy(cfg, arenas)
        sizes = [int(s) for s in policy.discretization.sizes()]
        agent = TabularAgent(policy, Phase2Config())
        _sim_rate(cfg, "random", 8, 0.05)  # compile (or load the numba cache) outside the measurement
        _actor_trials(cfg, agent, arenas, 0.0, batch_size, seed=1)  # one warm-up trial
        bar.mark(f"{sum(sizes) / len(sizes):.0f} prototypes per action", n=1)
        sim_steps = sim_s = 0.0
        totals = {"steps": 0.0, "tuples": 0.0, "slice_s": 0.0, "message_s": 0.0}
        for r in range(rounds):
            bar.show(status=f"round {r + 1}/{rounds}: simulator")
            start = time.perf_counter()
            rate = _sim_rate(cfg, "random", arenas, seconds)
            took = time.perf_counter() - start
            sim_steps, sim_s = sim_steps + rate * took, sim_s + took
            bar.mark(f"simulator {rate / 1e6:.2f} M robot-steps/s", n=bar.n + 1)
            bar.show(status=f"round {r + 1}/{rounds}: actor slice")
            part = _actor_trials(cfg, agent, arenas, seconds, batch_size, seed=2 + r)
            totals = {key: totals[key] + part[key] for key in totals}
            bar.mark(f"actor {part['steps'] / part['slice_s'] / 1e3:.0f} k robot-steps/s", n=bar.n + 1)
    actor_rate = totals["steps"] / totals["slice_s"]
    sim_rate = sim_steps / sim_s
    return {
        "benchmark": "actor",
        "scenario": cfg.name,
        "arenas": arenas,
        "robots": cfg.n_robots,
        "robot_steps_per_s": round(actor_rate),
        "sim_robot_steps_per_s": round(sim_rate),
        "ratio": round(actor_rate / sim_rate, 4),
        "tuples_per_s": round(totals["tuples"] / (totals["slice_s"] + totals["message_s"])),
        "slice_tuples_per_s": round(totals["tuples"] / totals["slice_s"]),
        "message_share": round(totals["message_s"] / (totals["slice_s"] + totals["message_s"]), 4),
        "prototypes_per_action": sizes,
        "target": {"ratio": ACTOR_TARGET_RATIO},
        "meets_target": {"ratio": actor_rate / sim_rate >= ACTOR_TARGET_RATIO},
    }


def actor_table(out: dict[str, Any]) -> str:
    sizes = out["prototypes_per_action"]
    met = "met" if out["meets_target"]["ratio"] else "NOT met"
    return (
        f"actor slice: {out['robot_steps_per_s'] / 1e3:.0f} k robot-steps/s, {out['tuples_per_s'] / 1e3:.0f} k "
        f"tuples/s ({out['arenas']} arenas, {sum(sizes) / len(sizes):.0f} prototypes per action)\n"
        f"simulator:   {out['sim_robot_steps_per_s'] / 1e6:.2f} M robot-steps/s (random controller, same arenas)\n"
        f"ratio {out['ratio']:.3f} (target >= {out['target']['ratio']}: {met})"
    )
