"""A picture of a learned policy: one test arena under the policy, and the prototypes it learned per action.

The same geometry as the Rerun views (:mod:`monitor.geometry`), rendered with matplotlib so that a run folder and
the README carry a picture without a viewer. Usage::

    policy, header = load_policy("runs/x/policy.npz")
    policy_figure(policy, scenario_from_header(header), Path("runs/x/policy.png"))
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from algorithm.policy import Policy, PolicyController
from monitor.geometry import observed_targets, project_2d, q_colors
from sim import ScenarioConfig, evaluate
from sim.controllers import COMPASS_NAMES
from sim.world import Observation, WorldState

SNAPSHOT_STEP = 300
"""The step of test trial 0 shown in the arena panel (well past the start, when the robots have spread out)."""


def _snapshot(policy: Policy, cfg: ScenarioConfig, seed: int, step: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Robot and target positions of test trial 0 at ``step``, and the trial's metric A over ``step`` steps."""
    seen: dict[str, np.ndarray] = {}

    def on_step(world: WorldState, _obs: Observation) -> None:
        if world.t == step:
            seen["robots"], seen["targets"] = world.robot_pos[0].copy(), world.target_pos[0].copy()

    result = evaluate(cfg, PolicyController(policy), trials=1, steps=step, seed=seed, on_step=on_step)
    return seen["robots"], seen["targets"], float(result.coverage_per_trial[0])


def policy_figure(policy: Policy, cfg: ScenarioConfig, out: Path, seed: int = 0, step: int = SNAPSHOT_STEP) -> Path:
    """Write ``out`` (PNG): the arena of test trial 0 at ``step`` and each action's prototypes coloured by Q."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    robots, targets, coverage = _snapshot(policy, cfg, seed, step)
    observed = observed_targets(robots, targets, cfg.sensing_range)
    fig = Figure(figsize=(13.0, 5.6), layout="constrained")
    panels: Any = fig.subfigures(1, 2, width_ratios=[1.0, 1.45])
    left, right = panels[0], panels[1]
    ax: Any = left.subplots()
    ax.add_patch(Circle((0.0, 0.0), cfg.arena_radius, fill=False, color="0.3"))
    for x, y in robots:
        ax.add_patch(Circle((x, y), cfg.sensing_range, color="tab:blue", alpha=0.12, lw=0))
    ax.scatter(robots[:, 0], robots[:, 1], s=28, c="tab:blue", marker="^", label="robot (sensing disk)")
    ax.scatter(*targets[observed].T, s=30, c="tab:green", label="target, observed")
    ax.scatter(*targets[~observed].T, s=30, c="tab:red", label="target, unobserved")
    ax.set_xlim(-1.05 * cfg.arena_radius, 1.05 * cfg.arena_radius)
    ax.set_ylim(-1.05 * cfg.arena_radius, 1.05 * cfg.arena_radius)
    ax.set_aspect("equal")
    ax.legend(loc="lower left", fontsize=7, framealpha=0.8)
    ax.set_title(f"test trial {seed}, step {step}: {observed.sum()}/{len(targets)} observed (A = {coverage:.1f}%)")

    prototypes, q_values = policy.prototypes_by_action()
    points = [project_2d(p) for p in prototypes]
    colors = q_colors(q_values)
    scale = policy.discretization.scale
    # The masked feature value (nothing in view) sits far out; clip the panels to where the targets in view lie.
    reach = cfg.sensing_range / (1.0 if scale is None else float(scale[0]))
    axes = right.subplots(2, 4, sharex=True, sharey=True)
    for k, panel in enumerate(axes.flat):
        if k >= len(points):
            panel.set_visible(False)
            continue
        inside = (np.abs(points[k]) <= 1.2 * reach).all(axis=1)
        panel.scatter(*points[k][inside].T, s=9, c=colors[k][inside] / 255.0)
        panel.set_title(f"action {k} ({COMPASS_NAMES[k]}): {len(points[k])}", fontsize=8)
        panel.set_xlim(-1.2 * reach, 1.2 * reach)
        panel.set_ylim(-1.2 * reach, 1.2 * reach)
        panel.set_aspect("equal")
        panel.tick_params(labelsize=6)
    right.suptitle(
        "prototypes per action: (dx, dy) to the nearest target in view, standardized; colour = Q (viridis)",
        fontsize=9,
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out
