"""Exact nearest-prototype search of :meth:`~algorithm.discretization.Discretization.cells`, compiled with numba.

The actors' phase-2 slices spent 86% of their time in a float64 matmul + argmin per action. This kernel takes one
state at a time, all actions in one call, and per action:

1. splits the prototypes (once, when the index is built) into groups of at most ``GROUP``, each with its bounding
   box: at the widest empty gap of any dimension when that gap is wide (a presence bit or a shared flag separates
   prototypes by a gap, and a box that spans it bounds nothing), otherwise at the median of the widest dimension;
2. scans the group whose box is nearest the state, then every other group whose box is not further than the best
   distance found so far, in float32 SIMD loops (8–16 prototypes per instruction; a group is padded to ``GROUP``
   so that the loops have no scalar remainder, which measured 1.5x faster than looping to each group's size);
3. takes as candidates the prototypes within ``m + MARGIN · (m + |x|²)`` of the state, m the smallest float32
   distance: float32 rounding (of the state, and of the sum) moves a squared distance by less than
   10·2⁻²⁴·(d + |x|²), an eighth of the margin, so the float64 nearest is always among them; usually there is one
   (a distance that overflows float32 scans as +inf; when all do, every group is scanned and float64 decides);
4. with several, their float64 squared distances Σ_k (x_k − c_k)² decide, the lowest index on a tie.

A box's bound is a sum of float64 terms each no larger than the matching term of any of its prototypes' distances,
added in the same order, so (rounding being monotone) it never exceeds them: a group is skipped only when none of
its prototypes can be, or tie with, the nearest. The result is therefore exactly that of brute force over float64
squared distances with ties to the lowest index.

Measured (one core, a 228-prototypes-per-action policy, the states of a phase-2 trial), per state and all 8 actions:
the matmul 5.3 µs; brute force in numba float64 3.6 µs; ``scipy.spatial.cKDTree`` 2.6 µs; a numba k-d tree with
leaves of 8 (scalar and branchy: ≈ 35 distances and 9 nodes per action) 2.1 µs, 12% less when walking from each
robot's previous cells over 8-nearest-neighbour lists; this kernel 0.8–0.9 µs (≈ 1.6 groups of 64 scanned per
action). On ``frame9d`` policies (9 dimensions, four of them flags), against median cuts alone, the gap cuts measured
1.49 against 2.98 µs (195 prototypes per action), 2.55 against 6.52 µs (656); gaps of 0.1 / 0.3 of the widest range
gave 1.60 / 1.62 and 2.63 / 2.75 µs.

States whose features are exactly zero in some dimensions (an absent pair's zeroed offsets, a flag that is off)
are searched in fewer dimensions: for the zero set Z, |x − c|² = Σ_{k∉Z} (x_k − c_k)² + Σ_{k∈Z} c_k², so an index
built on the other dimensions plus one more coordinate √(Σ_{k∈Z} c_k²) (where every state sits at 0) gives the same
distances; its boxes are tighter, and the float64 decision still reads the full prototypes. Rounding the extra
coordinate to float32 moves a distance, and a box's bound, by < 3·2⁻²⁴ of itself, far inside the margin that both
the candidates and the skipped groups are judged with. On ``frame-cooperative`` a phase-2 trial's states fall into
14 zero sets, half of the states into the one with both pairs absent; the reduction took
the search from 1.93 to 1.06 µs per state (195 prototypes per action).

A flag that is on fixes a dimension as well as one that is off: given each dimension's *flag value* (what a feature
of 1 scales to), a state's fixed set F holds the dimensions where it is 0 or at that value, v_k the value it has
there, and |x − c|² = Σ_{k∉F} (x_k − c_k)² + Σ_{k∈F} (v_k − c_k)²: the same reduction with the extra coordinate
√(Σ_{k∈F} (v_k − c_k)²), and the same bounds (only the scanned coordinates of the state are rounded to float32, and
|x|² of the margin is taken over them). On make run's ``frame-guided`` policy the second and third largest sets of a
phase-2 trial's states (32 % and 9 %) scan 4 and 6 coordinates instead of 7 and 9, and the fourth (7 %: one target
in view, seen by a teammate too) has one free dimension (below).

A fixed set that leaves at most one dimension free (on ``frame9d``: a robot that sees one target and nothing else,
42 % of a phase-2 trial's states, and one that sees one target a teammate sees too, 7 %) is searched on a *grid
index*: |x − c|² = Σ_{k free} (x_k − c_k)² + r_c with r_c = Σ_{k fixed} (v_k − c_k)². The grid cuts a range of each
free coordinate into ``GRID_SIDES`` equal intervals and keeps, per action and cell (a box B), the prototypes whose
smallest distance over the box, L_c = Σ_{k free} (distance from c_k to B's interval)² + r_c, is at most
(1 + ``GRID_SLACK``) times the smallest largest distance over it, min_c′ U_c′ with U_c′ = Σ_{k free}
max((lo_k − c′_k)², (hi_k − c′_k)²) + r_c′. Any other prototype is further than that prototype c′ at every point of
the box by a factor beyond 1 + 10⁻⁹, far more than float64 rounding (≈ 10 ulp of the sums, and of L and U) can undo,
so the nearest prototype under the float64 sums, and every prototype tying with it, is on the list. With one
candidate it is the answer; with several, their float64 squared distances Σ_k (x_k − c_k)², summed as above, decide
(the lists are in index order: the lowest index on a tie). A state outside the grid's range goes to the fixed set's
reduced index. On make run's ``frame-guided`` policy (223 prototypes per action, the states of two phase-2 trials
searched in one call), per state and 8 actions: one free dimension 0.61 µs on the reduced index, 0.14 µs on a grid of
256 cells, 0.04 µs on 4 096; three free (a target and a robot in view, 32 %) 0.79 µs on the reduced index, 0.81 /
0.49 / 0.39 / 0.26 µs on grids of 8 / 12 / 16 / 24 intervals a side (built in 8 / 24 / 56 / 181 ms). Inside a
phase-2 slice, where each call searches a step's few thousand states and the simulator runs between calls, grids
of three free dimensions (their lists take megabytes) made the slice no faster, 2.91–2.97 M robot-steps/s against
2.99–3.09 M without them on the loaded machine, so only fixed sets with one free dimension or none are gridded.

Shapes: N states, L actions, G groups (all actions), d dimensions (d′ scanned: d, or d − |Z| + 1).

Over 400 lines: the index (groups, reduced sets, grids) and the kernels that read it share one layout of flat
arrays and one proof of exactness (above), and numba compiles them together; apart, each half would restate both.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

GROUP = 64
"""Prototypes per group [measured on a 228-per-action policy, µs per state: 16: 1.7, 32: 1.1, 64: 0.8, 128: 1.6]."""
GAP_SIDE = 8
"""Fewest prototypes a gap cut leaves on either side (a smaller part would be a group of mostly padding)."""
GAP_SHARE = 0.2
"""A gap this wide, relative to the widest dimension's range, is cut before any median [measured, module docstring]."""
MARGIN = 1e-5
"""Relative candidate margin of the float32 pass (8x the float32 error bound derived above)."""
_FAR = 3e38
"""Coordinate of the padding prototypes: their float32 squared distances overflow to +inf, so they never win the
minimum, and the float64 decision skips them (index -1)."""


REDUCE_MIN = 32
"""States of one zero set in a call below which they go to the full index (a reduced index costs ≈ 3 ms to build
once, and each set one more kernel call) [choice]."""
REDUCED_CACHE = 64
"""Reduced indexes kept per prototype set; beyond it, new zero sets use the full index [choice: a frame9d policy
meets 14]."""
GRID_SIDES = (2048,)
"""Intervals a side of the grid index of a fixed set with 1, 2, … free dimensions; one with more uses its reduced
index [measured, module docstring: one free dimension only. With a cell set per action 256 and 2048 intervals gave
the same slice speed; on the union cells (one set of ≈ 1 350 prototypes, whose lists are longer) a phase-2 trial's
states took 0.353 / 0.294 / 0.274 / 0.277 µs each at 256 / 1 024 / 2 048 / 4 096, and `bench actor` rose by ≈ 4 %]."""
GRID_SLACK = 1e-9
"""Relative margin of a grid index's candidate lists (10⁶ times float64 rounding of a 10-term sum)."""
GRID_PAD = 0.25
"""A grid covers the prototypes' range of each free coordinate widened by this share of it on each side."""


@dataclass(frozen=True, slots=True)
class SearchIndex:
    """L prototype sets cut into groups, laid out for the kernel."""

    soa: np.ndarray
    """(G, d′, GROUP) float32: each group's prototypes in the scanned coordinates, one row per dimension, padded
    with far-away points."""
    points: np.ndarray
    """(G, GROUP, d) float64: the same prototypes, all d dimensions (exactly: they are float32 values), for the
    float64 decision."""
    index: np.ndarray
    """(G, GROUP) int64: the global index of each prototype (-1: padding)."""
    low: np.ndarray
    """(G, d′) float64: each group's bounding box in the scanned coordinates, lower corner ..."""
    high: np.ndarray
    """(G, d′) float64: ... and upper corner."""
    groups: np.ndarray
    """(L + 1,) int64: action a owns groups groups[a]:groups[a+1]."""
    fixed: np.ndarray | None = None
    """(d,) bool: the fixed set this index serves (scanned: the other dimensions, then √Σ (v_k − c_k)² over the set);
    None: every dimension, for any state."""


def build_index(
    prototypes: list[np.ndarray], offsets: np.ndarray, fixed: np.ndarray | None = None, value: np.ndarray | None = None
) -> SearchIndex:
    """The groups of per-action float32 prototype arrays (P_a, d); action a's first global index is ``offsets[a]``.

    ``fixed`` (d,) bool: an index for states that equal ``value`` (d,) (default 0) in exactly those dimensions
    (module docstring)."""
    everything = np.concatenate(prototypes)
    if fixed is None:
        scanned = everything
    else:
        scanned = _reduced(everything, fixed, np.zeros(fixed.size) if value is None else value)
    members: list[np.ndarray] = []
    groups = [0]
    start = 0
    for a, protos in enumerate(prototypes):
        part = scanned[start : start + len(protos)].astype(np.float64)
        members.extend(offsets[a] + idx for idx in _cut(part, np.arange(len(protos))))
        groups.append(len(members))
        start += len(protos)
    padded = np.full((len(members), GROUP, scanned.shape[1]), _FAR, np.float32)
    points = np.full((len(members), GROUP, everything.shape[1]), _FAR, np.float64)
    index = np.full((len(members), GROUP), -1, np.int64)
    for g, idx in enumerate(members):
        padded[g, : idx.size] = scanned[idx - offsets[0]]
        points[g, : idx.size] = everything[idx - offsets[0]]
        index[g, : idx.size] = idx
    boxes = [scanned[idx - offsets[0]].astype(np.float64) for idx in members]
    return SearchIndex(
        soa=np.ascontiguousarray(padded.transpose(0, 2, 1)),
        points=points,
        index=index,
        low=np.array([b.min(axis=0) for b in boxes]),
        high=np.array([b.max(axis=0) for b in boxes]),
        groups=np.array(groups, np.int64),
        fixed=fixed,
    )


def _reduced(points: np.ndarray, fixed: np.ndarray, value: np.ndarray) -> np.ndarray:
    """(P, d − |F| + 1) float32: the dimensions outside ``fixed``, then √(Σ (v_k − c_k)² over it) (module
    docstring)."""
    rest = np.sqrt(np.square(value[fixed] - points[:, fixed].astype(np.float64)).sum(axis=1))
    return np.concatenate([points[:, ~fixed], rest[:, None]], axis=1).astype(np.float32)


def _cut(points: np.ndarray, idx: np.ndarray) -> list[np.ndarray]:
    """``idx`` split until every part holds at most GROUP points: at the widest gap between consecutive values of
    any dimension (leaving ``GAP_SIDE`` points or more on each side) when it exceeds ``GAP_SHARE`` of the widest
    dimension's range, otherwise at the median of the widest dimension."""
    if idx.size <= GROUP:
        return [idx]
    sub = points[idx]
    spread = np.ptp(sub, axis=0)
    order = np.argsort(sub, axis=0, kind="stable")
    gaps = np.diff(np.take_along_axis(sub, order, axis=0), axis=0)[GAP_SIDE - 1 : idx.size - GAP_SIDE]
    if gaps.size and gaps.max() > GAP_SHARE * spread.max():
        at, dim = np.unravel_index(np.argmax(gaps), gaps.shape)
        ranked, half = idx[order[:, dim]], int(at) + GAP_SIDE
    else:
        ranked, half = idx[order[:, np.argmax(spread)]], idx.size // 2
    return _cut(points, ranked[:half]) + _cut(points, ranked[half:])


def search(index: SearchIndex, states: np.ndarray) -> np.ndarray:
    """(N, L) int64 global index of the nearest prototype of each action to each of ``states`` (N, d), finite; with
    ``index.fixed``, every state must have the index's values in those dimensions."""
    x = np.ascontiguousarray(states, dtype=np.float64)
    out = np.empty((x.shape[0], index.groups.size - 1), np.int64)
    fixed = index.fixed
    scanned = x if fixed is None else np.concatenate([x[:, ~fixed], np.zeros((x.shape[0], 1))], axis=1)
    _search(scanned, x, index.soa, index.points, index.index, index.low, index.high, index.groups, out)
    return out


@dataclass(frozen=True, slots=True)
class GridIndex:
    """The candidate lists of the states that have given values in every dimension but ``free`` (module
    docstring)."""

    free: np.ndarray
    """(k,) int64: the dimensions such a state is free in."""
    edges: np.ndarray
    """(k, n + 1) float64 ascending: interval j of free dimension q is edges[q, j] ≤ x ≤ edges[q, j + 1]."""
    starts: np.ndarray
    """(L · nᵏ + 1,) int64: the list of action a in cell c (row-major over the intervals) is
    members[starts[a·nᵏ + c] : starts[a·nᵏ + c + 1]]."""
    members: np.ndarray
    """(M,) int64 global indexes of the prototypes, ascending within each list."""
    points: np.ndarray
    """(P, d) float64 every prototype, row = global index − ``first``."""
    first: int
    """The global index of the first prototype."""


def build_grid(prototypes: list[np.ndarray], offsets: np.ndarray, free: np.ndarray, value: np.ndarray) -> GridIndex:
    """The grid index of the dimensions ``free`` (at most ``len(GRID_SIDES)``) over per-action float32 prototype
    arrays (P_a, d), for states whose other dimensions equal ``value`` (d,) (float32 values: the squares and the
    distances over the cells stay finite in float64)."""
    points = np.concatenate(prototypes).astype(np.float64)
    free = np.asarray(free, np.int64)
    fixed = np.ones(points.shape[1], bool)
    fixed[free] = False
    rest = np.square(np.asarray(value, np.float64)[fixed] - points[:, fixed]).sum(axis=1)
    side = GRID_SIDES[free.size - 1] if free.size else 1  # no free dimension: one cell
    edges = np.empty((free.size, side + 1))
    for q, k in enumerate(free):
        low, high = float(points[:, k].min()), float(points[:, k].max())
        pad = GRID_PAD * (high - low) if high > low else 1.0
        edges[q] = np.linspace(low - pad, high + pad, side + 1)
    # Rows of each action's prototypes (a shared codebook passes one set; ``offsets`` still names every action).
    bounds = np.concatenate([[0], np.cumsum([len(protos) for protos in prototypes])]).astype(np.int64)
    starts, members = _grid_lists(points, free, rest, edges, bounds, GRID_SLACK)
    return GridIndex(
        free=free, edges=edges, starts=starts, members=members + offsets[0], points=points, first=int(offsets[0])
    )


def search_grid(grid: GridIndex, states: np.ndarray) -> np.ndarray:
    """(N, L) int64 as :func:`search` for ``states`` (N, d) that have the grid's values in every dimension but
    ``grid.free``; a row outside the grid's range is -1 throughout."""
    x = np.ascontiguousarray(states, dtype=np.float64)
    cells = (grid.edges.shape[1] - 1) ** grid.free.size
    out = np.empty((x.shape[0], (grid.starts.size - 1) // cells), np.int64)
    _search_grid(x, grid.free, grid.edges, grid.starts, grid.members, grid.points, grid.first, out)
    return out


class Searcher:
    """The nearest-prototype search of one prototype set: the full index, and per fixed set met a grid index (at
    most ``len(GRID_SIDES)`` free dimensions) or a reduced index (built on first use, module docstring).

    ``flags`` (d,): each dimension's flag value (module docstring); None: only zeros fix a dimension."""

    def __init__(self, prototypes: list[np.ndarray], offsets: np.ndarray, flags: np.ndarray | None = None) -> None:
        self._prototypes = prototypes
        self._offsets = offsets
        # A flag value of 0 is a zero already (NaN: no state equals it), so every dimension has at most one bit set.
        self._flags = None if flags is None else np.where(np.asarray(flags) == 0, np.nan, flags).astype(np.float64)
        self.full = build_index(prototypes, offsets)
        self._reduced: dict[int, SearchIndex] = {}
        self._grids: dict[int, GridIndex] = {}

    def search(self, states: np.ndarray) -> np.ndarray:
        """(N, L) int64 as :func:`search` over the full index."""
        x = np.ascontiguousarray(states, dtype=np.float64)
        dim = x.shape[1]
        # A fixed set is keyed by its bits in one int64: bit k, dimension k is 0; bit d + k, it is at its flag value.
        if x.shape[0] < REDUCE_MIN or dim > (31 if self._flags is not None else 62):
            return search(self.full, x)
        keys = np.empty(x.shape[0], np.int64)
        _fixed_keys(x, np.full(dim, np.nan) if self._flags is None else self._flags, keys)
        order, starts, group_keys = (np.empty(x.shape[0], np.int64) for _ in range(3))
        groups = _group_rows(keys, order, starts, group_keys)
        out = np.empty((x.shape[0], self.full.groups.size - 1), np.int64)
        rest: list[np.ndarray] = []
        for g in range(groups):
            rows = order[starts[g] : starts[g + 1] if g + 1 < groups else x.shape[0]]
            key = int(group_keys[g])
            if rows.size >= REDUCE_MIN and dim - key.bit_count() <= len(GRID_SIDES):
                rows = self._search_grid(key, dim, x, rows, out)
                if rows.size == 0:
                    continue
            index = self._index(key, dim) if rows.size >= REDUCE_MIN else None
            if index is None:
                rest.append(rows)
            else:
                out[rows] = search(index, x[rows])
        if rest:
            rows = np.concatenate(rest)
            out[rows] = search(self.full, x[rows])
        return out

    @property
    def zero_sets(self) -> int:
        """Reduced indexes (of fixed sets) built so far."""
        return len(self._reduced)

    @property
    def grids(self) -> int:
        """Grid indexes built so far."""
        return len(self._grids)

    def _search_grid(self, key: int, dim: int, x: np.ndarray, rows: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Search ``rows`` of ``x`` (all in fixed set ``key``, at most ``len(GRID_SIDES)`` free dimensions) on its
        grid index into ``out``; returns the rows left for another index (those outside the grid's range)."""
        if key not in self._grids:
            fixed, value = self._fixed(key, dim)
            self._grids[key] = build_grid(self._prototypes, self._offsets, np.flatnonzero(~fixed), value)
        found = search_grid(self._grids[key], x[rows])
        inside = found[:, 0] >= 0
        out[rows[inside]] = found[inside]
        return rows[~inside]

    def _index(self, key: int, dim: int) -> SearchIndex | None:
        """The reduced index of fixed set ``key``, None to use the full one."""
        if key == 0:
            return None
        if key not in self._reduced:
            if len(self._reduced) >= REDUCED_CACHE:
                return None
            self._reduced[key] = build_index(self._prototypes, self._offsets, *self._fixed(key, dim))
        return self._reduced[key]

    def _fixed(self, key: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
        """(d,) bool the dimensions that fixed set ``key`` fixes, (d,) float64 their values (0 elsewhere)."""
        zero = (key >> np.arange(dim)) & 1 == 1
        on = (key >> (dim + np.arange(dim))) & 1 == 1
        values = np.zeros(dim) if self._flags is None else np.where(on, np.nan_to_num(self._flags), 0.0)
        return zero | on, values


# The helpers index whole arrays instead of taking row views (each view costs numba a reference-count increment and
# decrement), and loop to the group width read from the arrays: with the constant GROUP as trip count LLVM unrolled
# the loops into scalar code instead of vectorizing them.


@njit(cache=True, inline="always")
def _box_bound(x: np.ndarray, i: int, low: np.ndarray, high: np.ndarray, g: int) -> float:
    s = 0.0
    for k in range(x.shape[1]):
        t = max(low[g, k] - x[i, k], x[i, k] - high[g, k], 0.0)
        s += t * t
    return s


@njit(cache=True, inline="always")
def _scan(x32: np.ndarray, soa: np.ndarray, g: int, dist: np.ndarray, bits: np.ndarray, s: int) -> np.int32:
    """dist[s] = float32 squared distances from x32 to group g of ``soa``; returns the smallest one's bits.

    Non-negative floats order as their bit patterns do: the minimum is taken over integers, which LLVM vectorizes
    (a float minimum it does not).
    """
    width = dist.shape[1]
    x0 = x32[0]
    for p in range(width):
        t = x0 - soa[g, 0, p]
        dist[s, p] = t * t
    for k in range(1, soa.shape[1]):
        xk = x32[k]
        for p in range(width):
            t = xk - soa[g, k, p]
            dist[s, p] += t * t
    smallest = np.int32(0x7F800000)  # +inf
    for p in range(width):
        v = bits[s, p]
        smallest = v if v < smallest else smallest
    return smallest


@njit(cache=True)
def _search(
    xs: np.ndarray,
    x: np.ndarray,
    soa: np.ndarray,
    points: np.ndarray,
    index: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    groups: np.ndarray,
    out: np.ndarray,
) -> None:
    """``xs`` (N, d′) the states in the scanned coordinates, ``x`` (N, d) the same states for the decision."""
    n, dim = xs.shape
    most = int(np.max(groups[1:] - groups[:-1]))
    dist = np.empty((most, soa.shape[2]), np.float32)  # float32 distances of the groups scanned for one (state, action)
    bits = dist.view(np.int32)
    scanned = np.empty(most, np.int64)
    bounds = np.empty(most, np.float64)
    as_bits = np.empty(1, np.int32)
    as_float = as_bits.view(np.float32)  # reads the float32 whose bits are written to as_bits
    x32 = np.empty(dim, np.float32)
    for i in range(n):
        norm = 0.0  # |x|², the same in the scanned coordinates: the zero set adds nothing and its coordinate is 0
        for k in range(dim):
            x32[k] = xs[i, k]
            norm += xs[i, k] * xs[i, k]
        for a in range(groups.size - 1):
            first_group, end = groups[a], groups[a + 1]
            nearest_box = first_group
            for g in range(first_group, end):
                bounds[g - first_group] = _box_bound(xs, i, low, high, g)
                if bounds[g - first_group] < bounds[nearest_box - first_group]:
                    nearest_box = g
            smallest = _scan(x32, soa, nearest_box, dist, bits, 0)
            scanned[0] = nearest_box
            count = 1
            for g in range(first_group, end):
                as_bits[0] = smallest
                reach = _reach(as_float[0], norm)
                if g != nearest_box and bounds[g - first_group] <= reach:
                    smallest = min(smallest, _scan(x32, soa, g, dist, bits, count))
                    scanned[count] = g
                    count += 1
            as_bits[0] = smallest
            out[i, a] = _decide(x, i, _reach(as_float[0], norm), dist, scanned, count, points, index)


@njit(cache=True, inline="always")
def _reach(smallest: np.float32, norm: float) -> float:
    """m + MARGIN·(m + |x|²), m the smallest float32 distance: it bounds the float64 distance of that prototype."""
    m = np.float64(smallest)
    return m + MARGIN * (m + norm)


@njit(cache=True, inline="always")
def _decide(
    x: np.ndarray,
    i: int,
    reach: float,
    dist: np.ndarray,
    scanned: np.ndarray,
    count: int,
    points: np.ndarray,
    index: np.ndarray,
) -> int:
    """The nearest prototype among the candidates (float32 distance ≤ ``reach``) of the ``count`` scanned groups."""
    bound = np.float32(reach)
    width = dist.shape[1]
    candidates = 0
    where = count * width  # the first candidate's position s·width + p, as a minimum (a vectorizable reduction)
    for s in range(count):
        for p in range(width):
            inside = dist[s, p] <= bound
            candidates += inside
            where = min(where, s * width + p if inside else count * width)
    if candidates == 1:
        found = index[scanned[where // width], where % width]
        if found >= 0:
            return found
    # Several candidates (or inputs beyond float32's range): float64 decides, the lowest index on a tie.
    best = np.inf
    found = -1
    for s in range(count):
        g = scanned[s]
        for p in range(dist.shape[1]):
            if index[g, p] < 0 or (candidates > 0 and dist[s, p] > bound):
                continue
            d = 0.0
            for k in range(x.shape[1]):
                t = x[i, k] - points[g, p, k]
                d += t * t
            if found < 0 or d < best or (d == best and index[g, p] < found):
                best = d
                found = index[g, p]
    return found


@njit(cache=True)
def _group_rows(keys: np.ndarray, order: np.ndarray, starts: np.ndarray, group_keys: np.ndarray) -> int:
    """The rows of each distinct key together: group g (in order of first appearance) is ``group_keys[g]``, its
    rows ``order[starts[g]:starts[g + 1]]`` ascending; returns the number of groups. One hashed pass and a counting
    sort instead of numpy's stable argsort of the keys (2 % of a phase-2 slice)."""
    n = keys.shape[0]
    size = 2
    while size < 2 * n:
        size *= 2
    slot_key = np.empty(size, np.int64)
    slot_group = np.full(size, -1, np.int64)
    group_of = np.empty(n, np.int64)
    counts = np.zeros(n, np.int64)
    groups = 0
    for i in range(n):
        key = keys[i]
        h = (key * 2654435761) & (size - 1)  # Knuth's multiplicative hash; the product may wrap, as intended
        while slot_group[h] >= 0 and slot_key[h] != key:
            h = (h + 1) & (size - 1)
        if slot_group[h] < 0:
            slot_key[h] = key
            slot_group[h] = groups
            group_keys[groups] = key
            groups += 1
        group_of[i] = slot_group[h]
        counts[slot_group[h]] += 1
    start = 0
    for g in range(groups):
        starts[g] = start
        start += counts[g]
        counts[g] = starts[g]
    for i in range(n):
        g = group_of[i]
        order[counts[g]] = i
        counts[g] += 1
    return groups


@njit(cache=True)
def _fixed_keys(x: np.ndarray, flags: np.ndarray, out: np.ndarray) -> None:
    """:meth:`Searcher.search`'s key of each state's fixed set (``flags`` NaN: no flag value in that dimension); one
    pass instead of two (N, d) comparisons and products with the bits (3 % of a search)."""
    n, dim = x.shape
    for i in range(n):
        key = 0
        for k in range(dim):
            if x[i, k] == 0.0:
                key |= 1 << k
            elif x[i, k] == flags[k]:
                key |= 1 << (dim + k)
        out[i] = key


@njit(cache=True)
def _grid_lists(
    points: np.ndarray,  # (P, d) float64
    free: np.ndarray,  # (k,) int64
    rest: np.ndarray,  # (P,) float64: Σ over the fixed dimensions of (v − c)²
    edges: np.ndarray,  # (k, n + 1) float64
    bounds: np.ndarray,  # (L + 1,) int64: action a owns rows bounds[a]:bounds[a + 1] of points
    slack: float,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`build_grid`'s lists: (L · nᵏ + 1,) starts and the members as rows of ``points``."""
    k = free.size
    side = edges.shape[1] - 1
    cells = side**k
    members = [0 for _ in range(0)]  # an empty list of int64, typed for numba
    starts = np.zeros((bounds.size - 1) * cells + 1, np.int64)
    lo = np.empty(k)
    hi = np.empty(k)
    for a in range(bounds.size - 1):
        for c in range(cells):
            at = c
            for q in range(k - 1, -1, -1):
                lo[q] = edges[q, at % side]
                hi[q] = edges[q, at % side + 1]
                at //= side
            limit = np.inf
            for p in range(bounds[a], bounds[a + 1]):
                far = rest[p]
                for q in range(k):
                    v = points[p, free[q]]
                    far += max((lo[q] - v) ** 2, (hi[q] - v) ** 2)
                limit = min(limit, far)
            limit *= 1.0 + slack
            for p in range(bounds[a], bounds[a + 1]):
                near = rest[p]
                for q in range(k):
                    v = points[p, free[q]]
                    t = max(lo[q] - v, v - hi[q], 0.0)
                    near += t * t
                if near <= limit:
                    members.append(p)
            starts[a * cells + c + 1] = len(members)
    return starts, np.array(members, np.int64)


@njit(cache=True)
def _search_grid(
    x: np.ndarray,
    free: np.ndarray,
    edges: np.ndarray,
    starts: np.ndarray,
    members: np.ndarray,
    points: np.ndarray,
    first: int,
    out: np.ndarray,
) -> None:
    """:func:`search_grid`'s loop: the cell of each state, then per action its list (one: the answer; several: the
    float64 sums decide, the first of equal ones being the lowest index)."""
    n, dim = x.shape
    side = edges.shape[1] - 1
    cells = side**free.size
    for i in range(n):
        c = 0
        for q in range(free.size):
            u = x[i, free[q]]
            low, high = edges[q, 0], edges[q, side]
            if not (low <= u <= high):
                c = -1
                break
            # The division may round across an edge; the stored edges decide.
            j = min(int((u - low) / ((high - low) / side)), side - 1)
            while j > 0 and u < edges[q, j]:
                j -= 1
            while j < side - 1 and u > edges[q, j + 1]:
                j += 1
            c = c * side + j
        if c < 0:
            out[i, :] = -1
            continue
        for a in range(out.shape[1]):
            begin, end = starts[a * cells + c], starts[a * cells + c + 1]
            found = members[begin]
            if end - begin > 1:
                best = np.inf
                for s in range(begin, end):
                    p = members[s] - first
                    d = 0.0
                    for k in range(dim):
                        t = x[i, k] - points[p, k]
                        d += t * t
                    if d < best:
                        best = d
                        found = members[s]
            out[i, a] = found
