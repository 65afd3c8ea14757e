"""Reference runner for an ``ennc-ql-policy`` file, written from ``docs/reference/policy-file.md`` alone.

Only numpy and the standard library: nothing of the project is imported. It loads a policy file, simulates the
scenario its header names (all trials side by side, one seeded generator), drives every robot with the policy and
prints the mean coverage (metric A: % of targets in view of at least one robot, averaged over steps and trials)::

    python examples/policy_runner.py POLICY.npz --trials 10 --seed 0           # as `ennc-ql eval --policy POLICY.npz`
    python examples/policy_runner.py POLICY.npz --trials 10 --seed 0 --json    # per-trial figures as JSON
    python examples/policy_runner.py POLICY.npz --violate still-start          # break one documented rule

``--violate`` exists to show that the rules matter: ``still-start`` gives robots no search heading (lost robots
stand still), ``no-reflect`` never reflects the search heading off the wall (wandering robots stick to the rim).
Section names in the comments refer to docs/reference/policy-file.md.

Over 400 lines: the whole of the document's rules (scenario, state, frames, moves, trials) in one file of plain
numpy, as a client in another language would write it; it imports nothing of the project, by design.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]
Bools = NDArray[np.bool_]

REQUIRED = ("header", "prototypes", "labels", "offsets", "tables", "robot_table")
VIOLATIONS = ("still-start", "no-reflect")


@dataclass(frozen=True)
class PolicyFile:
    """The members of a policy file that acting needs (section "Members")."""

    header: dict[str, Any]
    prototypes: NDArray[np.float32]  # (P, d), unscaled
    offsets: Ints  # (L + 1,)
    tables: NDArray[np.float32]  # (R, P)
    robot_table: Ints  # (M,)
    scale: NDArray[np.float32] | None  # (d,) or absent

    @property
    def scenario(self) -> dict[str, Any]:
        return dict(self.header["scenario"])


def load_policy(path: Path) -> PolicyFile:
    """Read the ``.npz`` with numpy and check the format (section "Reading it with NumPy")."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    missing = [name for name in REQUIRED if name not in arrays]
    if missing:
        raise SystemExit(f"{path}: missing members {missing}")
    header = json.loads(arrays["header"].tobytes().decode("utf-8"))
    if header.get("format") != "ennc-ql-policy" or header.get("format_version") != 1:
        raise SystemExit(f"{path}: not an ennc-ql-policy file of format version 1")
    return PolicyFile(
        header=header,
        prototypes=arrays["prototypes"],
        offsets=arrays["offsets"].astype(np.int64),
        tables=arrays["tables"],
        robot_table=arrays["robot_table"].astype(np.int64),
        scale=arrays.get("scale"),
    )


def unit(angle: Floats) -> Floats:
    """(..., 2) unit vectors (cos, sin) of ``angle``."""
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def uniform_in_disk(rng: np.random.Generator, radius: float, shape: tuple[int, int]) -> Floats:
    """Uniform points in the disk: radius R·√u, angle uniform (section "Start of a trial")."""
    r = radius * np.sqrt(rng.random(shape))
    angle = rng.uniform(0.0, 2.0 * np.pi, shape)
    return r[..., None] * unit(angle)


@dataclass(frozen=True)
class Observation:
    """What every robot senses at one instant (sections "Sensing" and "The state")."""

    full_state: NDArray[np.float32]  # (E, m, 6): nearest target, furthest target, nearest robot (dx, dy)
    shared: NDArray[np.float32]  # (E, m, 2): another robot has the nearest / furthest target in view (1.0 / 0.0)
    lost: Bools  # (E, m): no target in view
    covered: Ints  # (E,): targets in view of at least one robot
    n_seen: Ints  # (E, m): targets in view
    sees_robot: Bools  # (E, m): another robot in view
    seen: Bools  # (E, m, n): robot i has target j in view
    watched: Bools  # (E, n): target j in view of some robot (what teammates report)
    memory: Floats | None = None  # (E, m, 2): frame11d-recall's offset to a remembered target beside one in view
    remembers: Bools | None = None  # (E, m): ``memory`` holds one


@dataclass(frozen=True)
class Memory:
    """Each robot's tracks of every target, for the ``frame11d-recall`` state (section "The state")."""

    position: Floats  # (E, m, n, 2) the target's world position at robot i's last sighting of it
    velocity: Floats  # (E, m, n, 2) its displacement per step estimated from robot i's sightings
    age: Ints  # (E, m, n) steps since that sighting; -1: never seen


def remember(
    policy: PolicyFile, obs: Observation, robots: Floats, targets: Floats, memory: Memory
) -> tuple[Observation, Memory]:
    """The observation ``frame11d-recall`` reads, and the tracks after this step; other states read ``obs``."""
    if policy.header["featurizer"]["name"] != "frame11d-recall":
        return obs, memory
    seen, known = obs.seen[..., None], (memory.age >= 0)[..., None]
    gap = np.where(known, memory.age[..., None] + 1, 1)
    position = np.where(seen, targets[:, None], memory.position)
    velocity = np.where(seen, np.where(known, (targets[:, None] - memory.position) / gap, 0.0), memory.velocity)
    age = np.where(obs.seen, 0, np.where(memory.age >= 0, memory.age + 1, -1))
    offset = position + age[..., None] * velocity - robots[:, :, None, :]
    d2 = offset[..., 0] * offset[..., 0] + offset[..., 1] * offset[..., 1]
    r2 = policy.scenario["sensing_range"] ** 2
    candidate = ~obs.seen & (age >= 0) & (age <= policy.scenario["recall_steps"]) & ~obs.watched[:, None, :]
    candidate &= d2 > r2  # a prediction inside the sensing range is known to be wrong
    remembers = candidate.any(axis=2)
    chosen = _pick(offset, np.argmin(np.where(candidate, d2, np.inf), axis=2))
    lost_one = remembers & obs.lost
    full = obs.full_state.copy()
    full[..., 0:2] = np.where(lost_one[..., None], chosen.astype(np.float32), full[..., 0:2])
    also = remembers & ~lost_one
    view = Observation(
        full_state=full,
        shared=obs.shared,
        lost=obs.lost & ~lost_one,
        covered=obs.covered,
        n_seen=np.where(lost_one, 1, obs.n_seen),
        sees_robot=obs.sees_robot,
        seen=obs.seen,
        watched=obs.watched,
        memory=np.where(also[..., None], chosen, 0.0).astype(np.float32).astype(np.float64),
        remembers=also,
    )
    return view, Memory(position=position, velocity=velocity, age=age)


def _pick(offsets: Floats, index: Ints) -> Floats:
    """(E, m, 2) the offset ``offsets[e, i, index[e, i]]``."""
    return np.take_along_axis(offsets, index[:, :, None, None], axis=2)[:, :, 0]


def sense(sc: dict[str, Any], robots: Floats, targets: Floats, rng: np.random.Generator) -> Observation:
    """In view is d² ≤ r_s², on true positions; only the reported offsets carry noise."""
    n_arenas, m, n = robots.shape[0], robots.shape[1], targets.shape[1]
    sigma, mask, r2 = sc["sensor_noise_std"], sc["mask_value"], sc["sensing_range"] * sc["sensing_range"]
    noise_t: Floats | float = 0.0
    noise_r: Floats | float = 0.0
    if sigma > 0.0:  # draw order: targets, then robots (section "Evaluation protocol")
        noise_t = rng.normal(0.0, sigma, (n_arenas, m, n, 2))
        noise_r = rng.normal(0.0, sigma, (n_arenas, m, m, 2))
    off_t = targets[:, None, :, :] - robots[:, :, None, :]  # [e, i, j]: target j minus robot i
    d2_t = off_t[..., 0] * off_t[..., 0] + off_t[..., 1] * off_t[..., 1]
    seen_t = d2_t <= r2
    off_r = robots[:, None, :, :] - robots[:, :, None, :]  # [e, i, k]: robot k minus robot i
    d2_r = off_r[..., 0] * off_r[..., 0] + off_r[..., 1] * off_r[..., 1]
    seen_r = (d2_r <= r2) & ~np.eye(m, dtype=bool)[None]
    # argmin / argmax return the first extreme: the lowest index wins a tie, as documented.
    nearest_t = np.argmin(np.where(seen_t, d2_t, np.inf), axis=2)
    furthest_t = np.argmax(np.where(seen_t, d2_t, -1.0), axis=2)
    nearest_r = np.argmin(np.where(seen_r, d2_r, np.inf), axis=2)
    any_t, any_r = seen_t.any(axis=2)[..., None], seen_r.any(axis=2)[..., None]
    full = np.concatenate(
        [
            np.where(any_t, _pick(off_t + noise_t, nearest_t), mask),
            np.where(any_t, _pick(off_t + noise_t, furthest_t), mask),
            np.where(any_r, _pick(off_r + noise_r, nearest_r), mask),
        ],
        axis=-1,
    ).astype(np.float32)
    others = seen_t.sum(axis=1, keepdims=True) - seen_t  # [e, i, j]: robots other than i with target j in view
    pair = np.stack([nearest_t, furthest_t], axis=-1)  # (E, m, 2) target indices
    shared = (np.take_along_axis(others, pair, axis=2) > 0) & any_t
    return Observation(
        full_state=full,
        shared=shared.astype(np.float32),
        lost=~any_t[..., 0],
        covered=seen_t.any(axis=1).sum(axis=1),
        n_seen=seen_t.sum(axis=2),
        sees_robot=any_r[..., 0],
        seen=seen_t,
        watched=seen_t.any(axis=1),
    )


def target_frame(obs: Observation) -> Floats:
    """(E, m, 2, 2) every robot's target frame, rows its x and y axes in world coordinates (section "The target
    frame"): x towards the nearest target in view, y a quarter turn counter-clockwise from it, mirrored so that the
    furthest target (with one target in view: the nearest robot) lies on the y >= 0 side; the world's axes when
    nothing is in view."""
    f = obs.full_state.astype(np.float64)
    seen = obs.n_seen
    d = np.sqrt(f[..., 0] * f[..., 0] + f[..., 1] * f[..., 1])
    has_axis = (seen >= 1) & (d > 1e-9)
    safe = np.where(has_axis, d, 1.0)
    x_axis = np.where(has_axis[..., None], f[..., 0:2] / safe[..., None], np.array([1.0, 0.0]))
    y_axis = np.stack([-x_axis[..., 1], x_axis[..., 0]], axis=-1)
    side = np.where(
        seen >= 2,
        (f[..., 2:4] * y_axis).sum(axis=-1),
        np.where(obs.sees_robot & (seen >= 1), (f[..., 4:6] * y_axis).sum(axis=-1), 0.0),
    )
    y_axis = np.where((side < 0.0)[..., None], -y_axis, y_axis)
    return np.stack([x_axis, y_axis], axis=-2)


def law_force(obs: Observation, law: dict[str, float]) -> Floats:
    """(E, m, 2) the pull F of the force law ``law`` on the six numbers, the shared flags and a remembered target
    beside one in view (section "The law frame")."""
    f = obs.full_state.astype(np.float64)

    def profile(d: Floats) -> Floats:
        do1, do2, do3, do4 = law["do1"], law["do2"], law["do3"], law["do4"]
        rise = np.where(d <= do1, -1.0 + d / do1, (d - do1) / (do2 - do1))
        fall = np.where(d <= do3, 1.0, 1.0 - (d - do3) / (do4 - do3))
        return np.where(d <= do2, rise, np.where(d <= do4, fall, 0.0))

    def repulsion(d: Floats) -> Floats:
        dr1, dr2 = law["dr1"], law["dr2"]
        return np.where(d <= dr1, -1.0, np.where(d <= dr2, -1.0 + (d - dr1) / (dr2 - dr1), 0.0))

    def pull(offset: Floats, present: Bools, weight: Floats, size) -> Floats:
        d = np.sqrt(offset[..., 0] * offset[..., 0] + offset[..., 1] * offset[..., 1])
        on = present & (d > 1e-12)
        safe = np.where(on, d, 1.0)
        return np.where(on[..., None], (weight * size(safe) / safe)[..., None] * offset, 0.0)

    w = law["shared_target_weight"]
    force = pull(f[..., 0:2], obs.n_seen >= 1, np.where(obs.shared[..., 0] > 0, w, 1.0), profile)
    force = force + pull(f[..., 2:4], obs.n_seen >= 2, np.where(obs.shared[..., 1] > 0, w, 1.0), profile)
    force = force + pull(f[..., 4:6], obs.sees_robot, np.ones(obs.lost.shape), repulsion)
    if obs.remembers is not None and obs.memory is not None:
        force = force + pull(obs.memory.astype(np.float64), obs.remembers, np.ones(obs.lost.shape), profile)
    return force


def law_frame(obs: Observation, law: dict[str, float], heading: Floats | None = None) -> Floats:
    """(E, m, 2, 2) every robot's law frame (section "The law frame"): x along the law's pull; y a quarter turn
    counter-clockwise from it, mirrored where the target frame is; where the law pulls nowhere, the target frame, or
    given the search ``heading`` (E, m, 2), x along it and y as above (``no_pull`` = ``search-heading``)."""
    force = law_force(obs, law)
    target = target_frame(obs)
    norm = np.sqrt(force[..., 0] * force[..., 0] + force[..., 1] * force[..., 1])
    pulls = norm > 1e-12
    x_axis = force / np.where(pulls, norm, 1.0)[..., None]
    # The target frame's handedness: +1 where its y is its x turned counter-clockwise, -1 where it is mirrored.
    turned = target[..., 1, 0] * -target[..., 0, 1] + target[..., 1, 1] * target[..., 0, 0]
    if heading is not None:
        x_axis = np.where(pulls[..., None], x_axis, heading)
        pulls = np.ones_like(pulls)
    y_axis = np.stack([-x_axis[..., 1], x_axis[..., 0]], axis=-1) * np.where(turned >= 0.0, 1.0, -1.0)[..., None]
    return np.where(pulls[..., None, None], np.stack([x_axis, y_axis], axis=-2), target)


def featurize(policy: PolicyFile, obs: Observation) -> NDArray[np.float32]:
    """(E·m, d) states by the featurizer's name (section "The state")."""
    full = obs.full_state.reshape(-1, 6)
    name = policy.header["featurizer"]["name"]
    if name == "collab6d":
        return full
    if name == "shared8d":
        return np.concatenate([full, obs.shared.reshape(-1, 2)], axis=1)
    if name == "local2d":
        return full[:, 2:4] if policy.scenario["local_target"] == "furthest" else full[:, 0:2]
    f = obs.full_state.astype(np.float64)
    has_target, has_second, has_robot = obs.n_seen >= 1, obs.n_seen >= 2, obs.sees_robot
    present = [has_target, has_second, has_robot]
    pairs = [np.where(p[..., None], f[..., k : k + 2], 0.0) for p, k in zip(present, (0, 2, 4), strict=True)]
    flags = [has_second[..., None].astype(np.float64), has_robot[..., None].astype(np.float64)]
    if name == "present10d":
        columns = [pairs[0], pairs[1], flags[0], pairs[2], flags[1], obs.shared]
        return np.concatenate(columns, axis=-1).reshape(full.shape[0], -1).astype(np.float32)
    frame = target_frame(obs)
    distance = np.where(has_target, np.sqrt((f[..., 0:2] ** 2).sum(axis=-1)), 0.0)[..., None]
    # An offset in the frame: its components along the frame's x and y axes.
    furthest, robot = (np.einsum("...k,...dk->...d", pair, frame) for pair in pairs[1:])
    if name in ("frame9d", "frame11d-recall"):
        columns = [distance, furthest, flags[0], robot, flags[1], obs.shared]
        if name == "frame11d-recall":
            memory = np.zeros_like(f[..., 0:2]) if obs.memory is None else obs.memory
            length = np.sqrt((memory**2).sum(axis=-1, keepdims=True))
            columns.append(np.einsum("...k,...dk->...d", memory / np.maximum(length, 1e-300), frame))
        return np.concatenate(columns, axis=-1).reshape(full.shape[0], -1).astype(np.float32)
    if name == "frame7d":
        mask = policy.scenario["mask_value"]
        distance = np.where(has_target[..., None], distance, mask)
        furthest = np.where(has_target[..., None], np.einsum("...k,...dk->...d", f[..., 2:4], frame), mask)
        robot = np.where(has_robot[..., None], robot, mask)
        columns = [distance, furthest, robot, obs.shared]
        return np.concatenate(columns, axis=-1).reshape(full.shape[0], -1).astype(np.float32)
    raise SystemExit(f"unknown featurizer {name!r}")


def cells(policy: PolicyFile, states: NDArray[np.float32]) -> Ints:
    """(N, L) cell of each state under each action: nearest prototype, ``scale`` as divisor, lowest j on a tie."""
    x = (states if policy.scale is None else states / policy.scale).astype(np.float64)
    n_actions = policy.offsets.size - 1
    out = np.empty((x.shape[0], n_actions), dtype=np.int64)
    for a in range(n_actions):
        lo, hi = policy.offsets[a], policy.offsets[a + 1]
        protos = policy.prototypes[lo:hi]
        c = (protos if policy.scale is None else protos / policy.scale).astype(np.float64)
        d2 = ((x[:, None, :] - c[None, :, :]) ** 2).sum(axis=-1)
        out[:, a] = lo + np.argmin(d2, axis=1)
    return out


def greedy(policy: PolicyFile, cell: Ints, rows: Ints) -> Ints:
    """(N,) argmax_a tables[row, cell[:, a]], lowest action on a tie (np.argmax takes the first maximum); with a
    ``law_margin`` δ, action 0 unless the best value beats action 0's by more than δ."""
    q = policy.tables[rows[:, None], cell]
    best = np.argmax(q, axis=1)
    margin = float(policy.header.get("law_margin", 0.0))
    if margin == 0.0:
        return best
    return np.where(q.max(axis=1) - q[:, 0] > margin, best, 0)


def reflect(heading: Floats, pos: Floats, radius: float) -> Floats:
    """Search headings reflected off the wall where the robot stands on it and the heading points outward."""
    r = np.sqrt(pos[..., 0] * pos[..., 0] + pos[..., 1] * pos[..., 1])[..., None]
    normal = pos / np.maximum(r, 1e-300)
    outward = (heading[..., 0] * normal[..., 0] + heading[..., 1] * normal[..., 1])[..., None]
    at_wall = (r >= radius - 1e-9) & (outward > 0)
    return np.where(at_wall, heading - 2.0 * outward * normal, heading)


def move_targets(
    sc: dict[str, Any], pos: Floats, vel: Floats, speed: Floats, rng: np.random.Generator
) -> tuple[Floats, Floats]:
    """Turn with target_turn_prob (speed kept), move, reflect specularly off the circle (section "Moving")."""
    turn = rng.random(speed.shape) < sc["target_turn_prob"]
    new_angle = rng.uniform(0.0, 2.0 * np.pi, speed.shape)
    vel = np.where(turn[..., None], speed[..., None] * unit(new_angle), vel)
    pos = pos + vel
    radius = sc["arena_radius"]
    r = np.sqrt(pos[..., 0] * pos[..., 0] + pos[..., 1] * pos[..., 1])[..., None]
    out = r > radius
    u = pos / r
    reflected_pos = pos - 2.0 * (r - radius) * u
    vn = (vel[..., 0] * u[..., 0] + vel[..., 1] * u[..., 1])[..., None]
    reflected_vel = vel - 2.0 * vn * u
    return np.where(out, reflected_pos, pos), np.where(out, reflected_vel, vel)


def move_robots(pos: Floats, displacement: Floats, radius: float) -> Floats:
    """Move, then project back onto the circle (no bounce) where outside."""
    pos = pos + displacement
    r = np.sqrt(pos[..., 0] * pos[..., 0] + pos[..., 1] * pos[..., 1])[..., None]
    return np.where(r > radius, pos * (radius / r), pos)


def run(policy: PolicyFile, trials: int, steps: int, seed: int, violate: str | None = None) -> Floats:
    """(trials,) coverage of each trial in %, following section "One test trial, step by step"."""
    sc, head = policy.scenario, policy.header
    rng = np.random.default_rng(seed)
    m, n, radius, speed = sc["n_robots"], sc["n_targets"], sc["arena_radius"], sc["robot_speed"]
    robots = uniform_in_disk(rng, radius, (trials, m))
    targets = uniform_in_disk(rng, radius, (trials, n))
    target_speed = rng.uniform(0.0, sc["target_speed_frac"] * speed, (trials, n))
    target_vel = target_speed[..., None] * unit(rng.uniform(0.0, 2.0 * np.pi, (trials, n)))
    heading = unit(rng.uniform(0.0, 2.0 * np.pi, (trials, m)))
    if violate == "still-start":
        heading = np.zeros_like(heading)
    directions = np.array([a["direction"] for a in sorted(head["actions"], key=lambda a: a["index"])])
    # Files without an action set name their moves in the world's frame (section "Header").
    action_set = head.get("action_set", {"frame": "world"})
    relative = action_set["frame"] in ("target", "law")
    frame = np.broadcast_to(np.eye(2), (trials, m, 2, 2))  # each robot's frame as of its last decision
    # Table row of every state: robot i of arena e is state e·m + i.
    rows = np.tile(policy.robot_table[np.arange(m) % policy.robot_table.size], trials)
    mode, every, cap = head["action_mode"], int(head["action_steps"]), int(head["max_action_steps"])
    action = np.zeros((trials, m), np.int64)
    start_cell = np.zeros((trials, m), np.int64)  # until_change: cell of the decision state under the action
    count = np.zeros((trials, m), np.int64)  # until_change: steps the action has lasted
    memory = Memory(
        position=np.zeros((trials, m, n, 2)), velocity=np.zeros((trials, m, n, 2)), age=np.full((trials, m, n), -1)
    )
    obs, memory = remember(policy, sense(sc, robots, targets, rng), robots, targets, memory)
    total = np.zeros(trials)
    for t in range(steps):
        # Lost robots: the heading turns for every robot, every step, before anyone decides.
        if violate != "no-reflect":
            heading = reflect(heading, robots, radius)
        if action_set.get("heading") == "law":
            force = law_force(obs, action_set["law"])
            norm = np.sqrt(force[..., 0] * force[..., 0] + force[..., 1] * force[..., 1])[..., None]
            heading = np.where(norm > 1e-12, force / np.where(norm > 1e-12, norm, 1.0), heading)
        # When robots decide: a shared clock (fixed) or each robot's own (until_change); everyone at t = 0.
        if mode == "fixed":
            decide = np.full((trials, m), t % every == 0)
            if t % every == 0:
                action = greedy(policy, cells(policy, featurize(policy, obs)), rows).reshape(trials, m)
        elif mode == "until_change":
            cell = cells(policy, featurize(policy, obs)).reshape(trials, m, -1)
            now = np.take_along_axis(cell, action[..., None], axis=2)[..., 0]
            decide = np.full((trials, m), True) if t == 0 else (now != start_cell) | (count >= cap)
            chosen = greedy(policy, cell.reshape(trials * m, -1), rows).reshape(trials, m)
            action = np.where(decide, chosen, action)
            start_cell = np.where(decide, np.take_along_axis(cell, action[..., None], axis=2)[..., 0], start_cell)
            count = np.where(decide, 1, count + 1)
        else:
            raise SystemExit(f"unknown action_mode {mode!r}")
        if relative:  # the frame of a relative move is fixed when the robot decides
            search = action_set.get("no_pull") == "search-heading"
            now = (
                law_frame(obs, action_set["law"], heading if search else None)
                if action_set["frame"] == "law"
                else target_frame(obs)
            )
            frame = np.where(decide[..., None, None], now, frame)
        # Lost robots: lost-ness is checked every step.
        # A move's direction given in the frame, in world coordinates: its x component along the frame's x axis.
        displacement = speed * np.einsum("...k,...kd->...d", directions[action], frame)
        lost = obs.lost[..., None]
        if head["lost_behaviour"] == "wander":
            displacement = np.where(lost, speed * heading, displacement)
        elif head["lost_behaviour"] == "stay":
            displacement = np.where(lost, 0.0, displacement)
        # Moving: targets draw their turns first (random stream order), then robots move; both from time-t positions.
        targets, target_vel = move_targets(sc, targets, target_vel, target_speed, rng)
        robots = move_robots(robots, displacement, radius)
        obs, memory = remember(policy, sense(sc, robots, targets, rng), robots, targets, memory)
        total += 100.0 * obs.covered / n
    return total / steps


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Run an ennc-ql policy file in a plain-numpy CMOMMT simulator.")
    parser.add_argument("policy", type=Path, help="the policy file (.npz)")
    parser.add_argument("--trials", type=int, default=10, help="trials run side by side (default 10)")
    parser.add_argument("--steps", type=int, default=1000, help="steps per trial (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of numpy.random.default_rng (default 0)")
    parser.add_argument("--violate", choices=VIOLATIONS, help="break one documented rule on purpose")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.trials < 1 or args.steps < 1:
        parser.error("--trials and --steps must be at least 1")
    policy = load_policy(args.policy)
    per_trial = run(policy, args.trials, args.steps, args.seed, args.violate)
    if args.json:
        out = {
            "policy": str(args.policy),
            "trials": args.trials,
            "steps": args.steps,
            "seed": args.seed,
            "violate": args.violate,
            "coverage_mean": float(per_trial.mean()),
            "coverage_std": float(per_trial.std()),
            "coverage_per_trial": [float(c) for c in per_trial],
        }
        print(json.dumps(out))
    else:
        runs = f"{args.trials} trials x {args.steps} steps, seed {args.seed}"
        print(f"{per_trial.mean():.2f} % of targets observed ({runs})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
