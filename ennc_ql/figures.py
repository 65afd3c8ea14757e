"""A picture of a learned policy: one test arena under the policy, and the prototypes it learned per action.

The same geometry and colours as the Rerun views (``monitor.geometry``, ``monitor.style``), rendered with
matplotlib so that a run folder and the README carry a picture without a viewer. Usage::

    policy, header = load_policy("runs/x/policy.npz")
    policy_figure(policy, scenario_from_header(header), Path("runs/x/policy.png"))
"""

from __future__ import annotations

import textwrap
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.policy import Policy, PolicyController
from monitor import style
from monitor.geometry import COLORMAP, observed_targets, project_2d, q_colors, q_range, view_subject
from sim import ScenarioConfig, evaluate
from sim.features import Featurizer
from sim.world import Observation, WorldState

SNAPSHOT_STEP = 300
"""The step of test trial 0 shown in the arena panel (well past the start, when the robots have spread out)."""


def _snapshot(
    policy: Policy, cfg: ScenarioConfig, seed: int, step: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Robot and target positions of test trial 0 at ``step``, each robot's move from there (its displacement over
    the next step: what the policy does), and the trial's metric A over the ``step + 1`` steps run."""
    seen: dict[str, np.ndarray] = {}

    def on_step(world: WorldState, _obs: Observation) -> None:
        if world.t == step:
            seen["robots"], seen["targets"] = world.robot_pos[0].copy(), world.target_pos[0].copy()
        elif world.t == step + 1:
            seen["next"] = world.robot_pos[0].copy()

    result = evaluate(cfg, PolicyController(policy), trials=1, steps=step + 1, seed=seed, on_step=on_step)
    return seen["robots"], seen["targets"], seen["next"] - seen["robots"], float(result.coverage_per_trial[0])


def _rgb(color: tuple[int, int, int]) -> tuple[float, float, float]:
    r, g, b = color
    return (r / 255, g / 255, b / 255)


def policy_figure(policy: Policy, cfg: ScenarioConfig, out: Path, seed: int = 0, step: int = SNAPSHOT_STEP) -> Path:
    """Write ``out`` (PNG): the arena of test trial 0 at ``step`` and each action's prototypes coloured by Q, with a
    Q colour bar and a caption; the arena's colours are the viewer's (Okabe and Ito's, colour-blind safe)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13.0, 6.4), layout="constrained")
    panels: Any = fig.subfigures(1, 2, width_ratios=[1.0, 1.45])
    _arena_panel(panels[0], policy, cfg, seed, step)
    _prototype_panels(panels[1], policy, cfg)
    fig.supxlabel(caption(policy.formulation.featurizer), fontsize=8, ha="left", x=0.01)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out


def _arena_panel(left: Any, policy: Policy, cfg: ScenarioConfig, seed: int, step: int) -> None:
    """Test trial ``seed`` at ``step`` under the policy: robots with their sensing disks, targets observed or not."""
    from matplotlib.patches import Circle

    robots, targets, moves, coverage = _snapshot(policy, cfg, seed, step)
    observed = observed_targets(robots, targets, cfg.sensing_range)
    ax: Any = left.subplots()
    ax.add_patch(Circle((0.0, 0.0), cfg.arena_radius, fill=False, color=_rgb(style.BOUNDARY)))
    for x, y in robots:
        ax.add_patch(Circle((x, y), cfg.sensing_range, color=_rgb(style.ROBOT), alpha=0.18, lw=0))
    ax.scatter(robots[:, 0], robots[:, 1], s=28, color=_rgb(style.ROBOT), marker="^", label="robot (sensing disk)")
    # What the policy does: each robot's move from here, drawn as a sensing radius long whatever its speed.
    length = np.linalg.norm(moves, axis=1, keepdims=True)
    arrows = np.divide(moves, length, out=np.zeros_like(moves), where=length > 0) * 0.8 * cfg.sensing_range
    ax.quiver(
        robots[:, 0],
        robots[:, 1],
        arrows[:, 0],
        arrows[:, 1],
        angles="xy",
        scale_units="xy",
        scale=1.0,
        width=0.006,
        color=_rgb(style.ROBOT),
        label="its move now (the policy's choice)",
    )
    ax.scatter(*targets[observed].T, s=30, color=_rgb(style.OBSERVED), label="target, observed")
    ax.scatter(*targets[~observed].T, s=30, color=_rgb(style.UNOBSERVED), marker="X", label="target, unobserved")
    ax.set_xlim(-1.05 * cfg.arena_radius, 1.05 * cfg.arena_radius)
    ax.set_ylim(-1.05 * cfg.arena_radius, 1.05 * cfg.arena_radius)
    ax.set_aspect("equal")
    ax.legend(loc="lower left", fontsize=7, framealpha=0.8)
    ax.set_title(
        f"test trial {seed} at step {step}: {observed.sum()} of {len(targets)} targets observed\n"
        f"over steps 0-{step + 1}: {coverage:.1f} % of the targets observed on average",
        fontsize=9,
    )


def _prototype_panels(right: Any, policy: Policy, cfg: ScenarioConfig) -> None:
    """One panel per move: its prototypes where :func:`monitor.geometry.project_2d` draws them, coloured by Q."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.patches import Circle

    prototypes, q_values = policy.prototypes_by_action()
    state = policy.formulation.featurizer
    points = [project_2d(p, state) for p in prototypes]
    colors = q_colors(q_values)
    scale = policy.discretization.scale
    column = state.view[0]
    # The masked feature value (nothing in view) sits far out; clip the panels to where the targets in view lie.
    reach = cfg.sensing_range / (1.0 if scale is None else float(scale[column]))
    moves = policy.formulation.actions.moves
    axes = right.subplots(2, 4, sharex=True, sharey=True)
    for k, panel in enumerate(axes.flat):
        if k >= len(points):
            panel.set_visible(False)
            continue
        inside = (np.abs(points[k]) <= 1.2 * reach).all(axis=1)
        panel.add_patch(Circle((0.0, 0.0), reach, fill=False, color=_rgb(style.BOUNDARY), lw=0.8))
        panel.scatter(*points[k][inside].T, s=9, c=colors[k][inside] / 255.0)
        panel.set_title(f"{moves[k]}: {len(points[k])}", fontsize=8)
        panel.set_xlim(-1.2 * reach, 1.2 * reach)
        panel.set_ylim(-1.2 * reach, 1.2 * reach)
        panel.set_aspect("equal")
        panel.tick_params(labelsize=6)
    lo, hi = q_range(q_values)
    bar = right.colorbar(
        ScalarMappable(norm=Normalize(lo, hi if hi > lo else lo + 1.0), cmap=COLORMAP), ax=axes, shrink=0.8
    )
    bar.set_label("Q value of the move (mean over robots)", fontsize=8)
    bar.ax.tick_params(labelsize=7)
    subject = view_subject(state)
    right.suptitle(f"prototypes per move (count in the title): {subject}", fontsize=9)


def caption(featurizer: Featurizer) -> str:
    """The figure's caption: what the two panels show for prototypes of ``featurizer``'s state."""
    where = (
        "(x, y) of the second target in view in the robot's target frame (x towards the nearest target, the second "
        "mirrored to y >= 0; standardized units; the circle is the sensing range)"
        if featurizer.frame == "target"
        else "(dx, dy) from the robot to the nearest target in view (standardized units, north up; the circle is the "
        "sensing range)"
    )
    return textwrap.fill(
        "Left: one test trial under the learned policy, each robot's arrow the move the policy makes it take next; "
        "a target is observed when it lies within some robot's sensing disk. Right: the learned discretization, one "
        "panel per move: each dot is a prototype placed by "
        f"{where}, coloured by the Q value of making that move from there: brighter is better. States with nothing "
        "there in view lie outside the panels.",
        width=200,
    )
