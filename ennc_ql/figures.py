"""A picture of a learned policy: one test arena under the policy, the prototypes it learned per action, and the
move it chooses where (the move map).

The same geometry and colours as the Rerun views (``monitor.geometry``, ``monitor.style``), rendered with
matplotlib so that a run folder carries a picture without a viewer. Usage::

    policy, header = load_policy("runs/x/policy.npz")
    policy_figure(policy, scenario_from_header(header), Path("runs/x/policy.png"))
    grid = move_map(policy, scenario_from_header(header))     # the move map's numbers, without pixels

The move map colours a grid of states by the greedy move of one robot's table. The states are made the way the
robots' own are: a synthetic :class:`~sim.world.Observation` (one or two targets in view, no robot) passed through
the policy's featurizer, so masks, presence bits, the target frame and the policy's scaling are the learner's. For a
target-frame state the grid is where the second target lies in the nearest target's frame, the nearest at
:data:`NEAREST_FRACTION` of the sensing range; for a world-frame state, where the only target in view lies. One
panel per combination of the shared flags that the state can tell apart (a teammate observes the target too).
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
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
FIGURE_WIDTH = 13.0
"""Inches."""
MAP_CELLS = 100
"""Grid cells of the move map across the sensing disk's diameter."""
NEAREST_FRACTION = 0.5
"""The nearest target's distance in a target-frame move map, as a fraction of the sensing range: a typical one."""


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


def policy_figure(
    policy: Policy, cfg: ScenarioConfig, out: Path, seed: int = 0, step: int = SNAPSHOT_STEP, robot: int = 0
) -> Path:
    """Write ``out`` (PNG): the arena of test trial 0 at ``step`` and each action's prototypes coloured by Q, with a
    Q colour bar; below, the move map of ``robot``'s table with its legend; a caption. Every colour is one of Okabe
    and Ito's (colour-blind safe) but the Q scale's."""
    from matplotlib.figure import Figure

    grid = move_map(policy, cfg, robot)
    # A target-frame map is half disks (the y > 0 half), a world-frame one whole disks.
    map_height = 2.8 if grid.nearest is not None else 3.6
    fig = Figure(figsize=(FIGURE_WIDTH, 6.4 + map_height), layout="constrained")
    rows: Any = fig.subfigures(2, 1, height_ratios=[6.4, map_height])
    panels: Any = rows[0].subfigures(1, 2, width_ratios=[1.0, 1.45])
    _arena_panel(panels[0], policy, cfg, seed, step)
    _prototype_panels(panels[1], policy, cfg)
    _move_map_panels(rows[1], grid, policy, cfg)
    fig.supxlabel(caption(policy.formulation.featurizer, robot), fontsize=8, ha="left", x=0.01)
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


@dataclass(frozen=True, slots=True)
class MoveMap:
    """The greedy move of one robot's table over a grid of states, panel by panel: what :func:`move_map` computes
    and the figure draws. The grid point (x, y) is the second target in the nearest target's frame (``nearest`` set)
    or the only target in view seen from the robot (``nearest`` None), in world units."""

    xs: np.ndarray
    """(nx,) float64 x of the grid's columns."""
    ys: np.ndarray
    """(ny,) float64 y of the grid's rows."""
    moves: np.ndarray
    """(k, ny, nx) int64 the action index chosen at each grid point of each panel; -1 where no state is drawn:
    outside the sensing disk, or (target frame) a second target nearer than the nearest or on the mirrored side."""
    panels: tuple[str, ...]
    """(k,) what each panel holds fixed: which targets in view a teammate observes too."""
    nearest: float | None
    """The nearest target's distance, at (nearest, 0) in a target-frame map; None in a world-frame one."""
    robot: int
    """The robot whose table row chose the moves."""


def move_map(policy: Policy, cfg: ScenarioConfig, robot: int = 0, cells: int = MAP_CELLS) -> MoveMap:
    """The move map of ``policy`` (module docstring): ``cells`` grid points across the sensing disk's diameter
    (only its y > 0 half in the target frame, the half the mirror leaves), no robot in view, ``robot``'s table.

    Panels whose states are equal (a featurizer without shared flags) are given once, titled by the first.
    """
    featurizer = policy.formulation.featurizer
    reach = cfg.sensing_range
    xs = reach * ((np.arange(cells) + 0.5) * 2.0 / cells - 1.0)
    in_frame = featurizer.frame == "target"
    ys = xs[xs > 0.0] if in_frame else xs
    gx, gy = np.meshgrid(xs, ys)
    distance = np.hypot(gx, gy)
    nearest = NEAREST_FRACTION * reach if in_frame else None
    drawn = (distance <= reach) & (distance >= (nearest or 0.0))
    points = np.stack([gx[drawn], gy[drawn]], axis=-1)
    variants = _TWO_TARGETS if in_frame else _ONE_TARGET
    titles: list[str] = []
    states: list[np.ndarray] = []
    for shared, title in variants.items():
        obs = _observation(cfg, points, shared, nearest)
        state = featurizer.compute(cfg, obs).reshape(len(points), -1)
        if not any(np.array_equal(state, seen) for seen in states):
            titles.append(title)
            states.append(state)
    if len(titles) == 1:
        titles = ["any target in view observed by a teammate or not (the state cannot tell)"]
    chosen = policy.greedy(np.concatenate(states), np.full(len(points) * len(states), robot))
    moves = np.full((len(states), *gx.shape), -1, np.int64)
    moves[:, drawn] = chosen.reshape(len(states), -1)
    return MoveMap(xs=xs, ys=ys, moves=moves, panels=tuple(titles), nearest=nearest, robot=robot)


_TWO_TARGETS = {
    (False, False): "no teammate observes either target",
    (True, False): "a teammate observes the nearest",
    (False, True): "a teammate observes the second",
    (True, True): "a teammate observes both",
}
_ONE_TARGET = {(False, False): "no teammate observes the target", (True, True): "a teammate observes it too"}
"""The shared flags (nearest, furthest) of each panel: with one target in view it is both the nearest and the
furthest, as :func:`sim.world.sense` has it."""


def _observation(
    cfg: ScenarioConfig, points: np.ndarray, shared: tuple[bool, bool], nearest: float | None
) -> Observation:
    """What :func:`sim.world.sense` reports to n robots (one arena) that see no robot and, for ``points`` (n, 2): with
    ``nearest`` None, one target at each point; else the nearest target at (nearest, 0) and the second at the point
    (y > 0: the world's axes are then the target frame)."""
    n = len(points)
    features = np.full((1, n, 6), cfg.mask_value, np.float32)
    if nearest is None:
        features[0, :, 0:2] = features[0, :, 2:4] = points
    else:
        features[0, :, 0] = nearest
        features[0, :, 1] = 0.0
        features[0, :, 2:4] = points
    seen = 1 if nearest is None else 2
    watched = int(shared[0]) if nearest is None else int(shared[0]) + int(shared[1])
    return Observation(
        features=features,
        n_seen=np.full((1, n), seen, np.int32),
        sees_robot=np.zeros((1, n), np.bool_),
        covered=np.array([seen], np.int32),
        shared=np.broadcast_to(np.array(shared, np.bool_), (1, n, 2)).copy(),
        n_only=np.full((1, n), seen - watched, np.int32),
    )


def _move_map_panels(bottom: Any, grid: MoveMap, policy: Policy, cfg: ScenarioConfig) -> None:
    """One panel per :attr:`MoveMap.panels`, each grid point coloured by its move, and the legend of the moves."""
    from matplotlib.patches import Circle, Patch

    colors = np.array([_rgb(c) for c in style.MOVE_PALETTE])
    reach = cfg.sensing_range
    half = (grid.xs[1] - grid.xs[0]) / 2.0
    extent = (grid.xs[0] - half, grid.xs[-1] + half, grid.ys[0] - half, grid.ys[-1] + half)
    bottom.suptitle(_map_title(grid, policy), fontsize=9)
    content = bottom
    if grid.nearest is None:
        # One or two whole disks, as wide as tall: centred with their legend rather than spread over the width.
        width = 3.2 * len(grid.panels) + 1.6
        pad = max(FIGURE_WIDTH - width, 0.1) / 2.0
        content = bottom.subfigures(1, 3, width_ratios=[pad, width, pad])[1]
    axes = content.subplots(1, len(grid.panels), sharex=True, sharey=True, squeeze=False)[0]
    for panel, moves, title in zip(axes, grid.moves, grid.panels, strict=True):
        image = np.ones((*moves.shape, 3))
        image[moves >= 0] = colors[moves[moves >= 0]]
        panel.imshow(image, origin="lower", extent=extent, interpolation="nearest")
        panel.add_patch(Circle((0.0, 0.0), reach, fill=False, color=_rgb(style.BOUNDARY), lw=0.8))
        marks = [(0.0, 0.0, "^", _rgb(style.ROBOT))]
        if grid.nearest is not None:
            marks.append((grid.nearest, 0.0, "o", _rgb(style.OBSERVED)))
            # Inside it the second target would be the nearest.
            panel.add_patch(Circle((0.0, 0.0), grid.nearest, fill=False, color=_rgb(style.BOUNDARY), lw=0.8, ls="--"))
        for x, y, marker, color in marks:
            panel.scatter([x], [y], s=40, marker=marker, color=color, edgecolors="black", linewidths=0.8, zorder=3)
        panel.set_title(title, fontsize=8)
        panel.set_xlim(-1.05 * reach, 1.05 * reach)
        panel.set_ylim(-0.03 * reach if grid.nearest is not None else -1.05 * reach, 1.05 * reach)
        panel.set_aspect("equal")
        panel.tick_params(labelsize=6)
    moves_named = policy.formulation.actions.moves
    handles = [Patch(color=colors[k], label=name) for k, name in enumerate(moves_named)]
    content.legend(handles=handles, loc="outside right center", fontsize=8, title="move", title_fontsize=8)


def _map_title(grid: MoveMap, policy: Policy) -> str:
    row = int(policy.rows(np.array([grid.robot]))[0])
    table = "the team's table" if policy.tables.shape[0] == 1 else f"robot {grid.robot}'s table (row {row})"
    if grid.nearest is None:
        where = "where the only target in view lies, seen from the robot (north up)"
    else:
        where = (
            f"where the second target in view lies in the nearest target's frame, the nearest (green dot) at "
            f"{grid.nearest:g} (x: towards it; y: the second's side)"
        )
    return f"the move {table} chooses, by {where}; no robot in view"


def caption(featurizer: Featurizer, robot: int = 0) -> str:
    """The figure's caption: what the panels show for states of ``featurizer``, the move map of ``robot``'s table."""
    in_frame = featurizer.frame == "target"
    where = (
        "(x, y) of the second target in view in the robot's target frame (x towards the nearest target, the second "
        "mirrored to y >= 0; standardized units; the circle is the sensing range)"
        if in_frame
        else "(dx, dy) from the robot to the nearest target in view (standardized units, north up; the circle is the "
        "sensing range)"
    )
    point = (
        "each point where the second target in view may lie, in the same frame (world units; the nearest target the "
        "green dot, the robot the triangle; the other half is the mirror image)"
        if in_frame
        else "each point where the only target in view may lie, seen from the robot (world units, north up; the robot "
        "the triangle)"
    )
    return textwrap.fill(
        "Top left: one test trial under the learned policy, each robot's arrow the move the policy makes it take "
        "next; a target is observed when it lies within some robot's sensing disk. Top right: the learned "
        "discretization, one panel per move: each dot is a prototype placed by "
        f"{where}, coloured by the Q value of making that move from there: brighter is better. States with nothing "
        f"there in view lie outside the panels. Bottom: the move map, what the policy does: {point}, coloured by the "
        f"move robot {robot}'s Q table chooses in that state (made from such an observation as the robots' own are, "
        "no robot in view); one panel per set of targets a teammate observes too that the state tells apart. "
        "White: no such state.",
        width=200,
    )
