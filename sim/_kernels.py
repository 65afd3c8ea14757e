"""Fused per-arena loops of the simulator, compiled with numba.

numpy alone measured about 1 M robot-steps/s for sensing + moving (10x short of the 10 M target, docs/performance.md):
the (arena, robot, target) broadcasts allocate several temporaries per step. These kernels do one pass per arena and
write into caller-allocated outputs, so the public functions in :mod:`sim.world` stay pure.

They run on one thread: numba's OpenMP workers spin between the many short kernel calls and slowed the whole step
by up to 50x on 2 cores, and a single thread measured as fast. Parallelism comes from actor processes instead.

Shapes: E arenas, m robots, n targets; positions are float64 (E, m|n, 2).

Over 400 lines: every numba kernel of the simulator in one module, so that numba's cache and the kernels' shared
conventions (shapes, masks) live in one place.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_EPS = 1e-9


# Over 60 lines: one numba pass per arena that senses every pair once without temporaries; split, each part would
# repeat the pair loop.
@njit(cache=True)
def sense(
    robot_pos: np.ndarray,  # (E, m, 2) float64
    target_pos: np.ndarray,  # (E, n, 2) float64
    sensing_range: float,
    mask_value: float,
    noise_t: np.ndarray,  # (E, m, n, 2) float64 added to observed target offsets, or shape (0, 0, 0, 2)
    noise_r: np.ndarray,  # (E, m, m, 2) float64 added to observed robot offsets, or shape (0, 0, 0, 2)
    features: np.ndarray,  # out (E, m, 6) float32: nearest target, furthest target, nearest robot (dx, dy)
    n_seen: np.ndarray,  # out (E, m) int32: targets in view of each robot
    sees_robot: np.ndarray,  # out (E, m) bool: another robot in view
    covered: np.ndarray,  # out (E,) int32: targets in view of at least one robot
    shared: np.ndarray,  # out (E, m, 2) bool: another robot also has the nearest / furthest target in view
    n_only: np.ndarray,  # out (E, m) int32: targets in view of this robot and of no other
    sighted: np.ndarray,  # out (E, m, n) bool: robot i has target j in view (the tracks' sightings)
) -> None:
    n_arenas, m, _ = robot_pos.shape
    n = target_pos.shape[1]
    r2 = sensing_range * sensing_range
    noisy = noise_t.shape[0] > 0
    watchers = np.zeros(n, dtype=np.int32)
    near_j = np.zeros(m, dtype=np.int64)
    far_j = np.zeros(m, dtype=np.int64)
    for e in range(n_arenas):
        watchers[:] = 0
        in_view = sighted[e]
        for i in range(m):
            rx = robot_pos[e, i, 0]
            ry = robot_pos[e, i, 1]
            count = 0
            near_d2 = np.inf
            far_d2 = -1.0
            nx = ny = fx = fy = mask_value
            near_j[i] = far_j[i] = -1
            for j in range(n):
                dx = target_pos[e, j, 0] - rx
                dy = target_pos[e, j, 1] - ry
                d2 = dx * dx + dy * dy
                in_view[i, j] = d2 <= r2
                if d2 <= r2:
                    count += 1
                    watchers[j] += 1
                    if noisy:
                        dx += noise_t[e, i, j, 0]
                        dy += noise_t[e, i, j, 1]
                    # Ties keep the lowest index, so features do not depend on float noise in the ordering.
                    if d2 < near_d2:
                        near_d2 = d2
                        nx = dx
                        ny = dy
                        near_j[i] = j
                    if d2 > far_d2:
                        far_d2 = d2
                        fx = dx
                        fy = dy
                        far_j[i] = j
            bot_d2 = np.inf
            bx = by = mask_value
            for k in range(m):
                if k == i:
                    continue
                dx = robot_pos[e, k, 0] - rx
                dy = robot_pos[e, k, 1] - ry
                d2 = dx * dx + dy * dy
                if d2 <= r2 and d2 < bot_d2:
                    bot_d2 = d2
                    bx = dx
                    by = dy
                    if noisy:
                        bx += noise_r[e, i, k, 0]
                        by += noise_r[e, i, k, 1]
            features[e, i, 0] = nx
            features[e, i, 1] = ny
            features[e, i, 2] = fx
            features[e, i, 3] = fy
            features[e, i, 4] = bx
            features[e, i, 5] = by
            n_seen[e, i] = count
            sees_robot[e, i] = bot_d2 < np.inf
        c = 0
        for j in range(n):
            if watchers[j] > 0:
                c += 1
        covered[e] = c
        # Who else watches a target is known once every robot of the arena has been sensed.
        for i in range(m):
            shared[e, i, 0] = near_j[i] >= 0 and watchers[near_j[i]] > 1
            shared[e, i, 1] = far_j[i] >= 0 and watchers[far_j[i]] > 1
            alone = 0
            for j in range(n):
                if in_view[i, j] and watchers[j] == 1:
                    alone += 1
            n_only[e, i] = alone


@njit(cache=True)
def move(
    robot_pos: np.ndarray,  # (E, m, 2) float64
    robot_vel: np.ndarray,  # (E, m, 2) float64 displacement this step
    target_pos: np.ndarray,  # (E, n, 2) float64
    target_vel: np.ndarray,  # (E, n, 2) float64 displacement per step
    target_speed: np.ndarray,  # (E, n) float64
    turn: np.ndarray,  # (E, n) bool: draw a new heading this step
    new_angle: np.ndarray,  # (E, n) float64 radians, used where turn
    radius: float,
    out_robot_pos: np.ndarray,
    out_target_pos: np.ndarray,
    out_target_vel: np.ndarray,
) -> None:
    n_arenas, m, _ = robot_pos.shape
    n = target_pos.shape[1]
    for e in range(n_arenas):
        for i in range(m):
            x = robot_pos[e, i, 0] + robot_vel[e, i, 0]
            y = robot_pos[e, i, 1] + robot_vel[e, i, 1]
            r = math.sqrt(x * x + y * y)
            if r > radius:
                x *= radius / r
                y *= radius / r
            out_robot_pos[e, i, 0] = x
            out_robot_pos[e, i, 1] = y
        for j in range(n):
            vx = target_vel[e, j, 0]
            vy = target_vel[e, j, 1]
            if turn[e, j]:
                vx = target_speed[e, j] * math.cos(new_angle[e, j])
                vy = target_speed[e, j] * math.sin(new_angle[e, j])
            x = target_pos[e, j, 0] + vx
            y = target_pos[e, j, 1] + vy
            r = math.sqrt(x * x + y * y)
            if r > radius:
                # Specular reflection on the circle: mirror the overshoot and the radial velocity component.
                ux = x / r
                uy = y / r
                back = 2.0 * (r - radius)
                x -= back * ux
                y -= back * uy
                vn = vx * ux + vy * uy
                vx -= 2.0 * vn * ux
                vy -= 2.0 * vn * uy
            out_target_pos[e, j, 0] = x
            out_target_pos[e, j, 1] = y
            out_target_vel[e, j, 0] = vx
            out_target_vel[e, j, 1] = vy


@njit(cache=True)
def override_moves(
    move: np.ndarray,  # (E, m, 2) float64, overwritten in place
    searching: np.ndarray,  # (E, m) bool: robots that search instead
    heading: np.ndarray,  # (E, m, 2) float64 unit search headings
    speed: float,
    stopped: np.ndarray,  # (E, m) bool: robots that do not move (wins over searching)
) -> None:
    """The trial step's two overrides of the held actions' moves in one pass: two masked numpy writes over (E, m, 2)
    cost ≈ 40 µs each per step of 5 000 robots."""
    n_arenas, m, _ = move.shape
    for e in range(n_arenas):
        for i in range(m):
            if stopped[e, i]:
                move[e, i, 0] = 0.0
                move[e, i, 1] = 0.0
            elif searching[e, i]:
                move[e, i, 0] = speed * heading[e, i, 0]
                move[e, i, 1] = speed * heading[e, i, 1]


@njit(cache=True)
def difference_redundancy(
    n_seen: np.ndarray,  # (E, m) int32
    n_only: np.ndarray,  # (E, m) int32
    penalty: np.float32,
    out: np.ndarray,  # out (E, m) float32
) -> None:
    """The ``difference-redundancy`` reward of :mod:`sim.features` in one pass, in float32 as numpy computes it:
    the targets only this robot sees, less ``penalty`` where it sees targets but only ones a teammate sees too."""
    n_arenas, m = n_only.shape
    for e in range(n_arenas):
        for i in range(m):
            redundant = np.float32(1.0) if n_seen[e, i] > 0 and n_only[e, i] == 0 else np.float32(0.0)
            out[e, i] = np.float32(n_only[e, i]) - penalty * redundant


@njit(cache=True)
def decision_rewards(
    decide: np.ndarray,  # (E, m) bool: robots that chose their action before this step
    earned: np.ndarray,  # (E, m) float32: the value summed over the held action's earlier steps
    value: np.ndarray,  # (E, m) float32: this step's value
    held: np.ndarray,  # (E, m) int64: steps the action has lasted, this one included
    lost: np.ndarray,  # (E, m) bool: tuples that end because the learner lost every target
    ends: np.ndarray,  # (E, m) bool: tuples that end on this step
    lost_reward: np.float32,
    out_earned: np.ndarray,  # out (E, m) float32
    out_mean: np.ndarray,  # out (E, m) float32: the mean value over the action's steps
    out_reward: np.ndarray,  # out (E, m) float32: the reward of the tuples that end, 0 elsewhere
) -> None:
    """A per-decision reward's bookkeeping of :func:`sim.trial.step_trial` in one pass, with numpy's arithmetic
    (float32 sums; the mean divided in float64, then rounded to float32): seven (E, m) numpy calls were 3 % of a
    phase-2 slice."""
    n_arenas, m = decide.shape
    for e in range(n_arenas):
        for i in range(m):
            total = (np.float32(0.0) if decide[e, i] else earned[e, i]) + value[e, i]
            mean = np.float32(np.float64(total) / np.float64(held[e, i]))
            out_earned[e, i] = total
            out_mean[e, i] = mean
            if not ends[e, i]:
                out_reward[e, i] = np.float32(0.0)
            elif lost[e, i]:
                out_reward[e, i] = lost_reward
            else:
                out_reward[e, i] = mean


@njit(cache=True, inline="always")
def _f_target(d: float, do1: float, do2: float, do3: float, do4: float) -> float:
    if d <= do1:
        return -1.0 + d / do1
    if d <= do2:
        return (d - do1) / (do2 - do1)
    if d <= do3:
        return 1.0
    if d <= do4:
        return 1.0 - (d - do3) / (do4 - do3)
    return 0.0


@njit(cache=True, inline="always")
def _g_robot(d: float, dr1: float, dr2: float) -> float:
    if d <= dr1:
        return -1.0
    if d <= dr2:
        return -1.0 + (d - dr1) / (dr2 - dr1)
    return 0.0


@njit(cache=True, inline="always")
def _robot_push(
    robot_pos: np.ndarray, e: int, i: int, dr1: float, dr2: float, fx: float, fy: float
) -> tuple[float, float]:
    """(fx, fy) plus the repulsions of robot i's teammates within dr2 (< sensing range: robots it senses), added
    one by one onto the target forces (the order of the additions decides near-ties of the heading)."""
    m = robot_pos.shape[1]
    rx = robot_pos[e, i, 0]
    ry = robot_pos[e, i, 1]
    for k in range(m):
        if k == i:
            continue
        dx = robot_pos[e, k, 0] - rx
        dy = robot_pos[e, k, 1] - ry
        d = math.sqrt(dx * dx + dy * dy)
        if d > dr2 or d < _EPS:
            continue
        g = _g_robot(d, dr1, dr2) / d
        fx += g * dx
        fy += g * dy
    return fx, fy


@njit(cache=True, inline="always")
def _unit_or_kept(
    fx: float, fy: float, heading: np.ndarray, e: int, i: int, rx: float, ry: float, radius: float
) -> tuple[float, float]:
    """The force's direction, or with no force the kept heading reflected off the wall (so that a wandering robot
    does not stick to the rim)."""
    norm = math.sqrt(fx * fx + fy * fy)
    if norm > _EPS:
        return fx / norm, fy / norm
    hx = heading[e, i, 0]
    hy = heading[e, i, 1]
    r = math.sqrt(rx * rx + ry * ry)
    if r >= radius - _EPS:
        ux = rx / r
        uy = ry / r
        vn = hx * ux + hy * uy
        if vn > 0.0:
            hx -= 2.0 * vn * ux
            hy -= 2.0 * vn * uy
    return hx, hy


@njit(cache=True)
def force_heading(
    robot_pos: np.ndarray,  # (E, m, 2) float64
    target_pos: np.ndarray,  # (E, n, 2) float64
    heading: np.ndarray,  # (E, m, 2) float64 unit vectors kept when no force acts
    do1: float,
    do2: float,
    do3: float,
    do4: float,
    dr1: float,
    dr2: float,
    sensing_range: float,
    shared_weight: float,
    repel_robots: bool,
    radius: float,
    out_heading: np.ndarray,  # out (E, m, 2) float64 unit vectors
) -> None:
    """The force law on the TRUE position of every target within do4, sensed or not: the oracle A-CMOMMT, which
    reads positions beyond every robot's sensing range (kept as a labelled reference, ``a-cmommt-oracle``)."""
    n_arenas, m, _ = robot_pos.shape
    n = target_pos.shape[1]
    r2 = sensing_range * sensing_range
    for e in range(n_arenas):
        # Robots observing each target, so a robot can down-weight targets that others already cover.
        watchers = np.zeros(n, dtype=np.int64)
        if shared_weight != 1.0:
            for i in range(m):
                for j in range(n):
                    dx = target_pos[e, j, 0] - robot_pos[e, i, 0]
                    dy = target_pos[e, j, 1] - robot_pos[e, i, 1]
                    if dx * dx + dy * dy <= r2:
                        watchers[j] += 1
        for i in range(m):
            rx = robot_pos[e, i, 0]
            ry = robot_pos[e, i, 1]
            fx = 0.0
            fy = 0.0
            for j in range(n):
                dx = target_pos[e, j, 0] - rx
                dy = target_pos[e, j, 1] - ry
                d2 = dx * dx + dy * dy
                d = math.sqrt(d2)
                if d > do4 or d < _EPS:
                    continue
                w = 1.0
                if shared_weight != 1.0 and watchers[j] - (1 if d2 <= r2 else 0) > 0:
                    w = shared_weight
                f = w * _f_target(d, do1, do2, do3, do4) / d
                fx += f * dx
                fy += f * dy
            if repel_robots:
                fx, fy = _robot_push(robot_pos, e, i, dr1, dr2, fx, fy)
            out_heading[e, i, 0], out_heading[e, i, 1] = _unit_or_kept(fx, fy, heading, e, i, rx, ry, radius)


NEVER_SEEN = 1 << 40
"""Track age of a target a robot has never observed."""
TRACK_WORD = 32
"""Targets per word of a robot's bit set of known tracks (int64 words: shifts stay clear of the sign bit)."""


@njit(cache=True)
def _sightings(
    robot_pos: np.ndarray, target_pos: np.ndarray, e: int, r2: float, in_view: np.ndarray, watchers: np.ndarray
) -> None:
    """Arena ``e``: ``in_view[i, j]`` robot i senses target j, ``watchers[j]`` how many robots do."""
    m, n = in_view.shape
    watchers[:] = 0
    for i in range(m):
        for j in range(n):
            dx = target_pos[e, j, 0] - robot_pos[e, i, 0]
            dy = target_pos[e, j, 1] - robot_pos[e, i, 1]
            in_view[i, j] = dx * dx + dy * dy <= r2
            if in_view[i, j]:
                watchers[j] += 1


@njit(cache=True, inline="always")
def _sight(
    target_pos: np.ndarray,
    track_pos: np.ndarray,
    track_vel: np.ndarray,
    age: int,
    e: int,
    i: int,
    j: int,
    out_pos: np.ndarray,
    out_vel: np.ndarray,
) -> None:
    """Robot i's track of target j after sighting it: the position now and the mean displacement since its last
    sighting ``age`` + 1 steps ago (0 on a first). Inlined where it is called (numba IR), so a call per pair costs
    nothing; the ages are the caller's to write."""
    px = target_pos[e, j, 0]
    py = target_pos[e, j, 1]
    if age < NEVER_SEEN:
        gap = float(age + 1)
        out_vel[e, i, j, 0] = (px - track_pos[e, i, j, 0]) / gap
        out_vel[e, i, j, 1] = (py - track_pos[e, i, j, 1]) / gap
    else:
        out_vel[e, i, j, 0] = 0.0
        out_vel[e, i, j, 1] = 0.0
    out_pos[e, i, j, 0] = px
    out_pos[e, i, j, 1] = py


@njit(cache=True)
def _track(
    target_pos: np.ndarray,
    track_pos: np.ndarray,
    track_vel: np.ndarray,
    track_age: np.ndarray,
    e: int,
    in_view: np.ndarray,
    out_pos: np.ndarray,
    out_vel: np.ndarray,
    out_age: np.ndarray,
) -> None:
    """Arena ``e``: every robot's track of every target after this step's sightings ``in_view`` (m, n), its age in
    ``out_age``: a sighting takes the position now and the mean displacement since the last one (0 on a first);
    otherwise the track is kept and ages by one. One call per arena, not per pair: a call per pair passed seven
    arrays each time and made the tracks 12 times slower (3.2 ms against 0.26 ms a step for 500 arenas)."""
    m, n = in_view.shape
    for i in range(m):
        for j in range(n):
            age = track_age[e, i, j]
            if in_view[i, j]:
                _sight(target_pos, track_pos, track_vel, age, e, i, j, out_pos, out_vel)
                out_age[e, i, j] = 0
                continue
            out_pos[e, i, j, 0] = track_pos[e, i, j, 0]
            out_pos[e, i, j, 1] = track_pos[e, i, j, 1]
            out_vel[e, i, j, 0] = track_vel[e, i, j, 0]
            out_vel[e, i, j, 1] = track_vel[e, i, j, 1]
            out_age[e, i, j] = age + 1 if age < NEVER_SEEN else NEVER_SEEN


# Over 60 lines: A-CMOMMT's whole force law per robot in one numba pass (targets in view, tracked ones in the band,
# teammates' reports, robot repulsion); its parts share the per-robot accumulators.
@njit(cache=True)
def tracked_force_heading(
    robot_pos: np.ndarray,  # (E, m, 2) float64
    target_pos: np.ndarray,  # (E, n, 2) float64, read only where some robot senses the target
    heading: np.ndarray,  # (E, m, 2) float64 unit vectors kept when no force acts
    track_pos: np.ndarray,  # (E, m, n, 2) float64: robot i's last sighting of target j
    track_vel: np.ndarray,  # (E, m, n, 2) float64: its estimated displacement per step then
    track_age: np.ndarray,  # (E, m, n) int64: steps since that sighting before this step (NEVER_SEEN: none)
    do1: float,
    do2: float,
    do3: float,
    do4: float,
    dr1: float,
    dr2: float,
    sensing_range: float,
    shared_weight: float,
    cooperative: bool,
    predict_steps: int,
    reported_weight: float,
    radius: float,
    out_heading: np.ndarray,  # out (E, m, 2) float64 unit vectors
    out_pos: np.ndarray,  # out (E, m, n, 2) the tracks after this step's sightings
    out_vel: np.ndarray,  # out (E, m, n, 2)
    out_age: np.ndarray,  # out (E, m, n) int64
) -> None:
    """A-CMOMMT's force law on what a robot can know [Parker 2002: do4 is the *predictive tracking* range].

    A target's true position is read only where some robot senses it. Robot i is pulled by

    * every target it senses (d <= do3), weighted ``shared_weight`` when another robot senses it too (the
      teammates' reports A-CMOMMT assumes; ``cooperative`` only);
    * in the band (do3, do4]: its own last sighting of a target, predicted forward linearly from the observed
      position and velocity for at most ``predict_steps`` steps (a prediction that falls inside its sensing range
      while it does not see the target is known to be wrong and dropped); and, ``cooperative`` with
      ``reported_weight`` > 0, a target another robot senses now, at the reported position, weighted
      ``reported_weight`` (it is being observed already).

    ``cooperative`` also turns on the repulsion from robots within dr2 (< sensing range). A target first seen this
    step has velocity 0 until it is seen again; one seen again after a gap of k steps gets its mean displacement.
    """
    n_arenas, m, _ = robot_pos.shape
    n = target_pos.shape[1]
    r2 = sensing_range * sensing_range
    in_view = np.zeros((m, n), dtype=np.bool_)
    watchers = np.zeros(n, dtype=np.int64)
    for e in range(n_arenas):
        _sightings(robot_pos, target_pos, e, r2, in_view, watchers)
        _track(target_pos, track_pos, track_vel, track_age, e, in_view, out_pos, out_vel, out_age)
        for i in range(m):
            rx = robot_pos[e, i, 0]
            ry = robot_pos[e, i, 1]
            fx = 0.0
            fy = 0.0
            for j in range(n):
                age = out_age[e, i, j]
                if in_view[i, j]:
                    dx = target_pos[e, j, 0] - rx
                    dy = target_pos[e, j, 1] - ry
                    d = math.sqrt(dx * dx + dy * dy)
                    if d < _EPS:
                        continue
                    w = shared_weight if cooperative and watchers[j] > 1 else 1.0
                    f = w * _f_target(d, do1, do2, do3, do4) / d
                    fx += f * dx
                    fy += f * dy
                    continue
                w = 0.0
                if cooperative and watchers[j] > 0:
                    # Another robot reports it now: the report replaces any prediction (with weight 0 the robot
                    # leaves a target that is being observed to the teammate observing it).
                    dx = target_pos[e, j, 0] - rx
                    dy = target_pos[e, j, 1] - ry
                    w = reported_weight
                elif age <= predict_steps:
                    dx = track_pos[e, i, j, 0] + age * track_vel[e, i, j, 0] - rx
                    dy = track_pos[e, i, j, 1] + age * track_vel[e, i, j, 1] - ry
                    w = 1.0
                if w == 0.0:
                    continue
                d = math.sqrt(dx * dx + dy * dy)
                if d <= do3 or d > do4:
                    continue
                f = w * _f_target(d, do1, do2, do3, do4) / d
                fx += f * dx
                fy += f * dy
            if cooperative:
                fx, fy = _robot_push(robot_pos, e, i, dr1, dr2, fx, fy)
            out_heading[e, i, 0], out_heading[e, i, 1] = _unit_or_kept(fx, fy, heading, e, i, rx, ry, radius)


@njit(cache=True)
def target_frames(
    features: np.ndarray,  # (E, m, 6) float32: nearest target, furthest target, nearest robot (dx, dy), masked
    n_seen: np.ndarray,  # (E, m) int32
    sees_robot: np.ndarray,  # (E, m) bool
    out_frame: np.ndarray,  # out (E, m, 2, 2) float64: rows are the frame's x and y axes in world coordinates
) -> None:
    """The target frame of :func:`sim.actions.target_frame`, one pass per robot."""
    n_arenas, m, _ = features.shape
    for e in range(n_arenas):
        for i in range(m):
            nx = float(features[e, i, 0])
            ny = float(features[e, i, 1])
            d = math.sqrt(nx * nx + ny * ny)
            if n_seen[e, i] >= 1 and d > 1e-9:
                xx = nx / d
                xy = ny / d
            else:
                xx = 1.0
                xy = 0.0
            yx = -xy
            yy = xx
            side = 0.0
            if n_seen[e, i] >= 2:
                side = float(features[e, i, 2]) * yx + float(features[e, i, 3]) * yy
            elif sees_robot[e, i] and n_seen[e, i] >= 1:
                side = float(features[e, i, 4]) * yx + float(features[e, i, 5]) * yy
            if side < 0.0:
                yx = -yx
                yy = -yy
            out_frame[e, i, 0, 0] = xx
            out_frame[e, i, 0, 1] = xy
            out_frame[e, i, 1, 0] = yx
            out_frame[e, i, 1, 1] = yy


@njit(cache=True, inline="always")
def _state_pull(
    x: float, y: float, weight: float, do1: float, do2: float, do3: float, do4: float
) -> tuple[float, float]:
    """The pull of one target pair of a state's features, as :func:`sim.controllers._pull` computes it."""
    d = math.sqrt(x * x + y * y)
    if d <= 1e-12:
        return 0.0, 0.0
    s = weight * _f_target(d, do1, do2, do3, do4) / d
    return s * x, s * y


@njit(cache=True)
def state_forces(
    features: np.ndarray,  # (E, m, 6) float32: nearest target, furthest target, nearest robot (dx, dy), masked
    n_seen: np.ndarray,  # (E, m) int32
    sees_robot: np.ndarray,  # (E, m) bool
    shared: np.ndarray,  # (E, m, 2) bool
    memory: np.ndarray,  # (E, m, 2) offset of the remembered target (zeros without a memory)
    remembers: np.ndarray,  # (E, m) bool
    law: np.ndarray,  # (7,) do1, do2, do3, do4, dr1, dr2, shared_target_weight (1 for a law blind to sharing)
    out_force: np.ndarray,  # out (E, m, 2) float64
) -> None:
    """:class:`sim.controllers.StateForceController`'s force of every robot, summed in its order: the nearest target,
    the furthest, the nearest robot, the remembered target (its numpy version made a phase-2 slice's guided
    explorations a twentieth of the slice)."""
    do1, do2, do3, do4, dr1, dr2, w_shared = law[0], law[1], law[2], law[3], law[4], law[5], law[6]
    n_arenas, m, _ = features.shape
    for e in range(n_arenas):
        for i in range(m):
            fx = fy = 0.0
            # The nearest target (k = 0), then the furthest (k = 1), each present with k + 1 targets in view.
            for k in range(min(n_seen[e, i], 2)):
                w = w_shared if shared[e, i, k] else 1.0
                px, py = _state_pull(
                    np.float64(features[e, i, 2 * k]), np.float64(features[e, i, 2 * k + 1]), w, do1, do2, do3, do4
                )
                fx += px
                fy += py
            if sees_robot[e, i]:
                x = np.float64(features[e, i, 4])
                y = np.float64(features[e, i, 5])
                d = math.sqrt(x * x + y * y)
                if d > 1e-12:
                    s = _g_robot(d, dr1, dr2) / d
                    fx += s * x
                    fy += s * y
            if remembers[e, i]:
                px, py = _state_pull(np.float64(memory[e, i, 0]), np.float64(memory[e, i, 1]), 1.0, do1, do2, do3, do4)
                fx += px
                fy += py
            out_force[e, i, 0] = fx
            out_force[e, i, 1] = fy


@njit(cache=True)
def law_frames(
    features: np.ndarray,  # (E, m, 6) float32: nearest target, furthest target, nearest robot (dx, dy), masked
    n_seen: np.ndarray,  # (E, m) int32
    sees_robot: np.ndarray,  # (E, m) bool
    shared: np.ndarray,  # (E, m, 2) bool
    memory: np.ndarray,  # (E, m, 2) offset of the remembered target (zeros without a memory)
    remembers: np.ndarray,  # (E, m) bool
    law: np.ndarray,  # (7,) do1, do2, do3, do4, dr1, dr2, shared_target_weight
    target: np.ndarray,  # (E, m, 2, 2) float64 from target_frames
    heading: np.ndarray,  # (E, m, 2) float64 unit search headings, read where the law pulls nowhere and ``search``
    search: bool,
    out_frame: np.ndarray,  # out (E, m, 2, 2) float64: rows are the frame's x and y axes in world coordinates
) -> None:
    """The law frame of :class:`sim.actions.ActionSet` (``law`` and ``law-search`` sets): x along the pull of
    :class:`sim.controllers.StateForceController` (shared) on the same features, y a quarter turn counter-clockwise,
    mirrored as the target frame is. Where the law pulls nowhere: the target frame, or with ``search`` x along the
    robot's search heading (y turned and mirrored as above)."""
    force = np.empty((*n_seen.shape, 2))
    state_forces(features, n_seen, sees_robot, shared, memory, remembers, law, force)
    n_arenas, m, _ = features.shape
    for e in range(n_arenas):
        for i in range(m):
            fx = force[e, i, 0]
            fy = force[e, i, 1]
            norm = math.sqrt(fx * fx + fy * fy)
            if norm > 1e-12:
                xx = fx / norm
                xy = fy / norm
            elif search:
                xx = heading[e, i, 0]
                xy = heading[e, i, 1]
            else:
                out_frame[e, i] = target[e, i]
                continue
            # +1 where the target frame's y is its x turned counter-clockwise, -1 where it is mirrored.
            turned = target[e, i, 1, 0] * -target[e, i, 0, 1] + target[e, i, 1, 1] * target[e, i, 0, 0]
            side = 1.0 if turned >= 0.0 else -1.0
            out_frame[e, i, 0, 0] = xx
            out_frame[e, i, 0, 1] = xy
            out_frame[e, i, 1, 0] = -xy * side
            out_frame[e, i, 1, 1] = xx * side


@njit(cache=True)
def frame9d(
    features: np.ndarray,  # (E, m, 6) float32: nearest target, furthest target, nearest robot (dx, dy), masked
    n_seen: np.ndarray,  # (E, m) int32
    sees_robot: np.ndarray,  # (E, m) bool
    shared: np.ndarray,  # (E, m, 2) bool
    frame: np.ndarray,  # (E, m, 2, 2) float64 from target_frames
    out: np.ndarray,  # out (E, m, 9) float32: the frame9d state of sim.features
) -> None:
    """The ``frame9d`` state: the nearest target's distance, the furthest target's and the nearest robot's offsets
    in the target frame with presence flags (absent pairs at 0), the two shared flags."""
    n_arenas, m, _ = features.shape
    for e in range(n_arenas):
        for i in range(m):
            xx = frame[e, i, 0, 0]
            xy = frame[e, i, 0, 1]
            yx = frame[e, i, 1, 0]
            yy = frame[e, i, 1, 1]
            d = 0.0
            if n_seen[e, i] >= 1:
                nx = float(features[e, i, 0])
                ny = float(features[e, i, 1])
                d = math.sqrt(nx * nx + ny * ny)
            fx = fy = has_f = 0.0
            if n_seen[e, i] >= 2:
                ox = float(features[e, i, 2])
                oy = float(features[e, i, 3])
                fx = ox * xx + oy * xy
                fy = ox * yx + oy * yy
                has_f = 1.0
            bx = by = has_b = 0.0
            if sees_robot[e, i]:
                ox = float(features[e, i, 4])
                oy = float(features[e, i, 5])
                bx = ox * xx + oy * xy
                by = ox * yx + oy * yy
                has_b = 1.0
            out[e, i, 0] = d
            out[e, i, 1] = fx
            out[e, i, 2] = fy
            out[e, i, 3] = has_f
            out[e, i, 4] = bx
            out[e, i, 5] = by
            out[e, i, 6] = has_b
            out[e, i, 7] = 1.0 if shared[e, i, 0] else 0.0
            out[e, i, 8] = 1.0 if shared[e, i, 1] else 0.0


@njit(cache=True)
def memory_direction(
    memory: np.ndarray,  # (E, m, 2) float32: offset to the remembered target beside one in view (0, 0: none)
    frame: np.ndarray,  # (E, m, 2, 2) float64 from target_frames
    out: np.ndarray,  # out (E, m, ≥ 11) float32: columns 9 and 10 of the frame11d-recall state
) -> None:
    """The remembered target's direction, a unit vector in the target frame ((0, 0) without one): the numpy version
    (a norm, a division and two sums over every robot) was a sixth of a learning step."""
    n_arenas, m, _ = memory.shape
    for e in range(n_arenas):
        for i in range(m):
            # np.float64, not float(): numba's float() of a float32 stays float32.
            x = np.float64(memory[e, i, 0])
            y = np.float64(memory[e, i, 1])
            length = max(math.sqrt(x * x + y * y), 1e-300)
            ux = x / length
            uy = y / length
            # Summed from +0.0, as numpy's sum does: a zero direction reads +0.0, never -0.0.
            out[e, i, 9] = 0.0 + frame[e, i, 0, 0] * ux + frame[e, i, 0, 1] * uy
            out[e, i, 10] = 0.0 + frame[e, i, 1, 0] * ux + frame[e, i, 1, 1] * uy


@njit(cache=True)
def wander(
    robot_pos: np.ndarray,  # (E, m, 2) float64
    heading: np.ndarray,  # (E, m, 2) float64 unit headings
    radius: float,
    out: np.ndarray,  # out (E, m, 2) float64
) -> None:
    """:func:`sim.controllers.wander` in one pass: the numpy version was a sixth of a learning step."""
    n_arenas, m, _ = robot_pos.shape
    for e in range(n_arenas):
        for i in range(m):
            x, y = robot_pos[e, i, 0], robot_pos[e, i, 1]
            r = math.sqrt(x * x + y * y)
            nx, ny = x / max(r, 1e-300), y / max(r, 1e-300)
            hx, hy = heading[e, i, 0], heading[e, i, 1]
            outward = hx * nx + hy * ny
            if r >= radius - 1e-9 and outward > 0.0:
                out[e, i, 0], out[e, i, 1] = hx - 2.0 * outward * nx, hy - 2.0 * outward * ny
            else:
                out[e, i, 0], out[e, i, 1] = hx, hy


@njit(cache=True)
def pull_headings(
    force: np.ndarray,  # (E, m, 2) float64 the law's pull
    kept: np.ndarray,  # in/out (E, m, 2) float64 unit headings, reflected off the wall
) -> None:
    """A ``track`` action set's search headings: ``kept`` turned to the pull's direction wherever the law pulls
    (in numpy this turn took 2.5 % of an actor's step, py-spy of ``ennc-ql bench actor``)."""
    n_arenas, m, _ = force.shape
    for e in range(n_arenas):
        for i in range(m):
            fx, fy = force[e, i, 0], force[e, i, 1]
            norm = math.sqrt(fx * fx + fy * fy)
            if norm > 1e-12:
                kept[e, i, 0], kept[e, i, 1] = fx / norm, fy / norm


@njit(cache=True)
def frame_velocity(
    directions: np.ndarray,  # (L, 2) float64 unit moves in their frame
    actions: np.ndarray,  # (E, m) int64
    frame: np.ndarray,  # (E, m, 2, 2) float64: rows are the frame's axes in world coordinates
    speed: float,
    out: np.ndarray,  # out (E, m, 2) float64
) -> None:
    """Full-speed world displacements of moves named in each robot's frame (:meth:`sim.actions.ActionSet.velocity`)."""
    n_arenas, m = actions.shape
    for e in range(n_arenas):
        for i in range(m):
            lx, ly = directions[actions[e, i], 0], directions[actions[e, i], 1]
            for d in range(2):
                out[e, i, d] = speed * (lx * frame[e, i, 0, d] + ly * frame[e, i, 1, d])


@njit(cache=True)
def update_tracks(
    robot_pos: np.ndarray,  # (E, m, 2) float64
    target_pos: np.ndarray,  # (E, n, 2) float64, read only where some robot senses the target
    sighted: np.ndarray,  # (E, m, n) bool: robot i has target j in view now (``sense`` made it)
    track_pos: np.ndarray,  # in/out (E, m, n, 2) float64: robot i's last sighting of target j
    track_vel: np.ndarray,  # in/out (E, m, n, 2) float64: the target's displacement per step estimated then
    track_age: np.ndarray,  # in/out (E, m, n) int64: steps since that sighting (NEVER_SEEN: none)
    known: np.ndarray,  # in/out (E, m, ⌈n / TRACK_WORD⌉) int64: bit set of the targets robot i has a track of
    sensing_range: float,
    recall_steps: int,
    out_memory: np.ndarray,  # out (E, m, 2) float64: offset to the remembered target (0 where none)
    out_remembers: np.ndarray,  # out (E, m) bool: the robot has a remembered target
) -> None:
    """:func:`sim.recall.recall`'s tracks and remembered target, one pass per arena, updating the tracks in place.

    A sensed target's track takes its position now and its mean displacement since the robot's last sighting (0 on a
    first sighting), as :func:`tracked_force_heading` keeps them; any other track ages by one. A robot's remembered
    target is, of the targets it saw at most ``recall_steps`` steps ago, sees not now and no teammate sees now, the
    one whose prediction (the last sighting moved on by its velocity for the steps since) lies nearest; a prediction
    inside the sensing range is known to be wrong (the robot would see the target) and is passed over. Only the
    tracks a robot holds or sights now are read (``known`` and this step's sightings as bit sets: a robot holds one
    or two of ten): the loop over every robot-target pair, which read every age, was a ninth of a learning step."""
    n_arenas, m, _ = robot_pos.shape
    n = target_pos.shape[1]
    r2 = sensing_range * sensing_range
    seen = np.empty(m, np.int64)
    best = np.empty(m)
    for e in range(n_arenas):
        for i in range(m):
            best[i] = np.inf
            out_memory[e, i, 0] = 0.0
            out_memory[e, i, 1] = 0.0
        for w in range(known.shape[2]):
            first = TRACK_WORD * w
            watched = 0
            for i in range(m):
                bits = 0
                for b in range(min(TRACK_WORD, n - first)):
                    bits |= int(sighted[e, i, first + b]) << b
                seen[i] = bits
                watched |= bits
            for i in range(m):
                now = seen[i]
                relevant = now | known[e, i, w]
                known[e, i, w] = relevant
                j = first
                while relevant:
                    if relevant & 1:
                        age = track_age[e, i, j]
                        if (now >> (j - first)) & 1:
                            _sight(target_pos, track_pos, track_vel, age, e, i, j, track_pos, track_vel)
                            track_age[e, i, j] = 0
                        else:
                            age += 1
                            track_age[e, i, j] = age
                            if not (watched >> (j - first)) & 1 and age <= recall_steps:
                                dx = track_pos[e, i, j, 0] + age * track_vel[e, i, j, 0] - robot_pos[e, i, 0]
                                dy = track_pos[e, i, j, 1] + age * track_vel[e, i, j, 1] - robot_pos[e, i, 1]
                                d2 = dx * dx + dy * dy
                                if d2 > r2 and d2 < best[i]:
                                    best[i] = d2
                                    out_memory[e, i, 0] = dx
                                    out_memory[e, i, 1] = dy
                    relevant >>= 1
                    j += 1
        for i in range(m):
            out_remembers[e, i] = best[i] < np.inf


@njit(cache=True)
def remembered_view(
    features: np.ndarray,  # (E, m, 6) float32: the sensed features
    n_seen: np.ndarray,  # (E, m) int32
    memory: np.ndarray,  # (E, m, 2) float64 from update_tracks: offset to the remembered target
    remembers: np.ndarray,  # (E, m) bool from update_tracks
    out_features: np.ndarray,  # out (E, m, 6) float32
    out_n_seen: np.ndarray,  # out (E, m) int32
    out_memory: np.ndarray,  # out (E, m, 2) float32
    out_remembers: np.ndarray,  # out (E, m) bool
) -> None:
    """The view of :func:`sim.recall.recall` in one pass: a robot that sees no target and remembers one reads the
    remembered offset as its nearest target (one target in view); one that sees a target keeps its features and
    gets the remembered offset beside them."""
    n_arenas, m, k = features.shape
    for e in range(n_arenas):
        for i in range(m):
            for c in range(k):
                out_features[e, i, c] = features[e, i, c]
            out_n_seen[e, i] = n_seen[e, i]
            out_memory[e, i, 0] = 0.0
            out_memory[e, i, 1] = 0.0
            out_remembers[e, i] = False
            if not remembers[e, i]:
                continue
            if n_seen[e, i] == 0:
                out_features[e, i, 0] = np.float32(memory[e, i, 0])
                out_features[e, i, 1] = np.float32(memory[e, i, 1])
                out_n_seen[e, i] = 1
            else:
                out_memory[e, i, 0] = np.float32(memory[e, i, 0])
                out_memory[e, i, 1] = np.float32(memory[e, i, 1])
                out_remembers[e, i] = True
