"""The operators of one ENNC cycle as pure functions over tensors.

Every function takes tensors and returns new tensors (inputs are never modified), so each operator can be
checked on a hand-built case. Randomness is injected as tensors of uniform draws in [0, 1): the estimator in
:mod:`algorithm.ennc` draws them from its seeded ``torch.Generator``, a test can pass the draw it wants.

Shapes: N patterns of dimension d, P prototypes, C classes. Classes are indices ``0..C-1`` here; the caller's class
labels (``classes_``) live in the estimator. The per-cycle bookkeeping is the (prototype, class)
contingency table ``V`` (P, C) int64, with ``V[i, j] = |R_i ∩ S_j|``, and the per-cell pattern sums ``sums``
(P·C, d), row ``i·C + j`` holding the sum of the patterns of V_ij. Patterns are never looped over in Python.

Usage, one cycle by hand (what :class:`algorithm.ennc.ENNC` does 250 times)::

    region, score = nearest_prototype(X, prototypes)
    V = contingency(region, y, P, C)
    q = quality(V, labels, class_sizes)
    labels = relabel(V, labels)
    child_pos, child_lab = reproduce(X, region, y, V, labels, u)
    ...  # append the children, re-assign with nearest_among_new, drop empty regions, recompute V and q
    sums = cell_sums(X.T.contiguous(), region, y, P, C)
    owner = fight(prototypes, labels, q, k_fight, u_fight, u_win, C)
    prototypes = move(prototypes, labels, V, sums, owner)
    keep = die(q, u_die)

Over 400 lines: every numba kernel of ENNC in one module, next to each other because they share the cell layout.
"""

from __future__ import annotations

from typing import Any

import torch
from scipy.spatial import cKDTree
from torch import Tensor

#: Bytes of distance matrix evaluated per chunk when the caller gives no chunk size. On CPU a few MiB keeps
#: the block in cache between the matrix product and the row minimum (measured fastest on the 2-core
#: reference machine); on a GPU large chunks amortise kernel launches.
CPU_CHUNK_BYTES = 4 << 20
CUDA_CHUNK_BYTES = 256 << 20

#: :func:`refresh_nearest` falls back to a full pass when its partial work exceeds this fraction of one; the
#: gathers of the partial path cost about what this margin leaves.
REFRESH_FULL_FRACTION = 0.6

#: Build options of the k-d trees over the prototypes (one or two per cycle): an unbalanced tree with larger
#: leaves built in half the time and queried about 20 % faster on 7 000 6-D prototypes.
KD_TREE: dict[str, Any] = {"leafsize": 32, "balanced_tree": False}

#: Relative gap (to ``||x||² + max ||c||²``) under which two scores from different passes count as a tie;
#: float64 rounding of a 6-term dot product is about 1e-15 of that scale.
TIE_TOLERANCE = 1e-12


def default_chunk_rows(n_prototypes: int, device: torch.device, itemsize: int = 8) -> int:
    """Rows of X per distance block so that one (rows, P) block holds about the device's chunk budget.

    >>> default_chunk_rows(128, torch.device("cpu"))
    4096
    """
    budget = CUDA_CHUNK_BYTES if device.type == "cuda" else CPU_CHUNK_BYTES
    return max(256, budget // (max(1, n_prototypes) * itemsize))


def nearest_prototype(X: Tensor, prototypes: Tensor, chunk_rows: int | None = None) -> tuple[Tensor, Tensor]:
    """Index of the nearest prototype (Euclidean) of every pattern, computed in chunks of rows.

    Distances use the matrix form ``||c||² − 2·x·c`` (the ``||x||²`` term is the same for every prototype
    of a row and does not change the argmin), one GEMM per chunk, so memory stays at ``chunk_rows × P``.
    Ties go to the lowest prototype index: ``torch.min`` returns the first minimum, and a prototype that
    duplicates a lower-indexed one is never chosen (the GEMM may round two equal columns differently).
    Distinct prototypes within rounding (~1e-15 relative) of a tie are resolved by that rounding.

    Returns ``(index, score)``: int64 (N,) and the minimal ``||c||² − 2·x·c`` (N,), which
    :func:`nearest_among_new` uses to compare against prototypes added later without recomputing the rest.

    >>> X = torch.tensor([[0.0], [0.9], [3.0]], dtype=torch.float64)
    >>> nearest_prototype(X, torch.tensor([[0.0], [2.0]], dtype=torch.float64))[0].tolist()
    [0, 0, 1]
    """
    n = X.shape[0]
    rows = chunk_rows or default_chunk_rows(prototypes.shape[0], X.device, X.element_size())
    c_norm = (prototypes * prototypes).sum(dim=1).masked_fill(_duplicates(prototypes), float("inf"))
    proto_t = prototypes.T.contiguous()
    index = torch.empty(n, dtype=torch.int64, device=X.device)
    score = torch.empty(n, dtype=X.dtype, device=X.device)
    block = torch.empty((min(rows, n), prototypes.shape[0]), dtype=X.dtype, device=X.device)
    for start in range(0, n, rows):
        stop = min(n, start + rows)
        out = block[: stop - start]
        torch.addmm(c_norm, X[start:stop], proto_t, beta=1.0, alpha=-2.0, out=out)
        torch.min(out, dim=1, out=(score[start:stop], index[start:stop]))
    return index, score


def _duplicates(prototypes: Tensor) -> Tensor:
    """(P,) bool: rows equal to a row of lower index."""
    n_proto = prototypes.shape[0]
    duplicate = torch.zeros(n_proto, dtype=torch.bool, device=prototypes.device)
    if n_proto < 2:
        return duplicate
    # Equal rows have equal norms: only rows that share their norm with another need grouping (a row-wise
    # unique over all P rows cost a quarter of a cycle at P ≈ 7 000).
    norms, by_norm = torch.sort((prototypes * prototypes).sum(dim=1))
    tied = norms[1:] == norms[:-1]
    if not bool(tied.any()):
        return duplicate
    shares = torch.zeros(n_proto, dtype=torch.bool, device=prototypes.device)
    shares[1:] |= tied
    shares[:-1] |= tied
    rows = by_norm[shares]
    _, group = torch.unique(prototypes.index_select(0, rows), dim=0, return_inverse=True)
    first = torch.full_like(rows, n_proto).scatter_reduce_(0, group, rows, reduce="amin")
    duplicate[rows] = first[group] != rows
    return duplicate


def nearest_among_new(
    X: Tensor,
    prototypes: Tensor,
    index: Tensor,
    score: Tensor,
    first_new: int,
    chunk_rows: int | None = None,
    x_sq: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Update a nearest-prototype assignment after ``prototypes[first_new:]`` were appended.

    Only the N × (new) distances are computed; the result equals :func:`nearest_prototype` over all
    ``prototypes`` (see :func:`_keep_nearer` for ties). ``x_sq`` (N,) = ``||x||²`` is computed when not given.

    >>> X = torch.tensor([[0.0], [3.0]], dtype=torch.float64)
    >>> protos = torch.tensor([[0.0], [3.0]], dtype=torch.float64)
    >>> idx, sc = nearest_prototype(X, protos[:1])
    >>> nearest_among_new(X, protos, idx, sc, 1)[0].tolist()
    [0, 1]
    """
    x_sq = (X * X).sum(dim=1) if x_sq is None else x_sq
    new_index, new_score = nearest_prototype(X, prototypes[first_new:], chunk_rows)
    return _keep_nearer(X, x_sq, prototypes, index, score, new_index + first_new, new_score, chunk_rows)


# Over 60 lines: a numba kernel whose pruned search is one loop; split, numba would not share the bounds.
def refresh_nearest(
    X: Tensor,
    prototypes: Tensor,
    index: Tensor,
    score: Tensor,
    moved: Tensor,
    chunk_rows: int | None = None,
    x_sq: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """Nearest-prototype assignment after some prototypes moved and some were removed.

    ``index`` (N,) is the previous assignment re-indexed to the current P prototypes, with P where the
    pattern's prototype was removed; ``score`` its ``||c||² − 2·x·c``; ``moved`` (P,) bool flags prototypes
    whose position changed since; ``x_sq`` the patterns' ``||x||²`` (computed when not given).

    Only what can have changed is searched, with the centre–centre bound of accelerated k-means (Elkan 2003):
    for a pattern x of prototype a and any prototype p, ``d(x, p) ≥ d(a, p) − d(x, a)``, so p cannot take x
    while ``2·d(x, a) < d(a, p)``. Prototypes that did not move kept their distances, so the only candidates
    are: every other prototype for the patterns of a moved prototype, the moved prototypes for the others.
    Patterns that the bound does not settle are searched against those candidates; the patterns of a removed
    prototype against all. When that would cost more than :data:`REFRESH_FULL_FRACTION` of a full pass, the
    full pass is done instead. The result equals :func:`nearest_prototype`.

    >>> X = torch.tensor([[0.0], [3.5], [9.0]], dtype=torch.float64)
    >>> protos = torch.tensor([[0.0], [5.0], [10.0]], dtype=torch.float64)
    >>> idx, sc = nearest_prototype(X, protos)
    >>> protos[2] = 3.0  # prototype 2 moved next to pattern 1
    >>> refresh_nearest(X, protos, idx, sc, torch.tensor([False, False, True]))[0].tolist()
    [0, 2, 1]
    """
    n, n_proto = X.shape[0], prototypes.shape[0]
    x_sq = (X * X).sum(dim=1) if x_sq is None else x_sq
    # Row P of these tables stands for a removed prototype: treated as moved, never settled, at the origin
    # (so its score below is a harmless placeholder until the pattern is searched).
    moved_ext = torch.cat([moved, moved.new_ones(1)])
    centres = torch.cat([prototypes, prototypes.new_zeros((1, prototypes.shape[1]))])
    c_sq = (centres * centres).sum(dim=1)
    reach = torch.cat([_reach(prototypes, moved), prototypes.new_zeros(1)])
    # Row gathers use index_select/index_copy_: measured 2–3× faster than advanced indexing here.
    own_moved = moved_ext.index_select(0, index)
    index, score = index.clone(), score.clone()
    shifted = torch.nonzero(own_moved).squeeze(1)
    if shifted.numel():
        own = index.index_select(0, shifted)
        dots = torch.einsum("nd,nd->n", X.index_select(0, shifted), centres.index_select(0, own))
        score.index_copy_(0, shifted, c_sq.index_select(0, own) - 2.0 * dots)
    # Squared distance to the own prototype, padded by its rounding error so that the bound stays strict.
    dist_sq = score + x_sq * (1.0 + TIE_TOLERANCE) + TIE_TOLERANCE * c_sq.max()
    unsettled = dist_sq >= (0.25 * reach * reach).index_select(0, index)
    search_all = torch.nonzero(unsettled & own_moved).squeeze(1)
    search_moved = torch.nonzero(unsettled & ~own_moved).squeeze(1)
    moved_ids = torch.nonzero(moved).squeeze(1)
    cost = search_all.numel() * n_proto + search_moved.numel() * moved_ids.numel()
    if cost >= REFRESH_FULL_FRACTION * n * n_proto:
        return nearest_prototype(X, prototypes, chunk_rows)
    if search_all.numel():
        found_index, found_score = nearest_prototype(X.index_select(0, search_all), prototypes, chunk_rows)
        index.index_copy_(0, search_all, found_index)
        score.index_copy_(0, search_all, found_score)
    if search_moved.numel():
        x = X.index_select(0, search_moved)
        sub_index, sub_score = nearest_prototype(x, prototypes.index_select(0, moved_ids), chunk_rows)
        found_index, found_score = _keep_nearer(
            x,
            x_sq.index_select(0, search_moved),
            prototypes,
            index.index_select(0, search_moved),
            score.index_select(0, search_moved),
            moved_ids.index_select(0, sub_index),
            sub_score,
            chunk_rows,
        )
        index.index_copy_(0, search_moved, found_index)
        score.index_copy_(0, search_moved, found_score)
    return index, score


def _reach(prototypes: Tensor, moved: Tensor) -> Tensor:
    """(P,) distance from each prototype to the nearest other prototype that may now take its patterns:
    any other one if it moved, a moved one otherwise (∞ when there is none).

    Two k-d tree queries, O(P·log P): the (P, P) distance table they replace took a quarter of the cycle at
    1 851 prototypes on 5 000 patterns.
    """
    reach = torch.full((prototypes.shape[0],), float("inf"), dtype=prototypes.dtype, device=prototypes.device)
    if not bool(moved.any()) or prototypes.shape[0] < 2:
        return reach
    points = prototypes.cpu().numpy()
    is_moved = moved.cpu().numpy()
    # A moved prototype: its nearest other prototype (the second hit; the first is itself or a duplicate at 0).
    dist_all, _ = cKDTree(points, **KD_TREE).query(points[is_moved], k=2)
    reach[moved] = torch.as_tensor(dist_all[:, 1], dtype=prototypes.dtype, device=prototypes.device)
    if not is_moved.all():
        dist_moved, _ = cKDTree(points[is_moved], **KD_TREE).query(points[~is_moved], k=1)
        reach[~moved] = torch.as_tensor(dist_moved, dtype=prototypes.dtype, device=prototypes.device)
    return reach


def nearest_neighbours(prototypes: Tensor, k: int) -> Tensor:
    """(P, k) int64: the ``k`` nearest other prototypes of each prototype, nearest first (k < P).

    A k-d tree query (O(P·log P)) instead of the (P, P) distance table. A duplicate of a prototype counts as
    a neighbour at distance 0; the prototype itself never does.

    >>> nearest_neighbours(torch.tensor([[0.0], [1.0], [3.0]], dtype=torch.float64), 1).tolist()
    [[1], [0], [1]]
    """
    points = prototypes.cpu().numpy()
    _, hits = cKDTree(points, **KD_TREE).query(points, k=k + 1)
    hits = torch.as_tensor(hits.reshape(points.shape[0], k + 1), dtype=torch.int64)
    # The prototype itself is among the k + 1 hits unless more than k duplicates tie at 0: move it last
    # (stable, so the others keep their order) and drop the last column.
    is_self = hits == torch.arange(points.shape[0])[:, None]
    order = torch.argsort(is_self.to(torch.int8), dim=1, stable=True)
    return hits.gather(1, order[:, :k]).to(prototypes.device)


def _keep_nearer(
    x: Tensor,
    x_sq: Tensor,
    prototypes: Tensor,
    index: Tensor,
    score: Tensor,
    other_index: Tensor,
    other_score: Tensor,
    chunk_rows: int | None,
) -> tuple[Tensor, Tensor]:
    """Per pattern of ``x``, the nearer of two candidate prototypes scored in different passes.

    Two passes may round the same distance differently (duplicated prototypes occur: two prototypes
    representing the same patterns sit on the same centroid), so a pair within :data:`TIE_TOLERANCE` of a
    tie is rescored against all prototypes in one pass, where ties resolve as in :func:`nearest_prototype`.
    """
    scale = x_sq + (prototypes * prototypes).sum(dim=1).max()
    ties = torch.nonzero((other_score - score).abs() <= TIE_TOLERANCE * scale).squeeze(1)
    better = other_score < score
    index, score = torch.where(better, other_index, index), torch.where(better, other_score, score)
    if ties.numel():
        tie_index, tie_score = nearest_prototype(x.index_select(0, ties), prototypes, chunk_rows)
        index.index_copy_(0, ties, tie_index)
        score.index_copy_(0, ties, tie_score)
    return index, score


def contingency(region: Tensor, y: Tensor, n_prototypes: int, n_classes: int) -> Tensor:
    """Table ``V`` (P, C) int64 of pattern counts per (region, class), one ``bincount`` over ``region·C + y``.

    >>> contingency(torch.tensor([0, 0, 1]), torch.tensor([1, 0, 1]), 2, 2).tolist()
    [[1, 1], [0, 1]]
    """
    cells = region * n_classes + y
    return torch.bincount(cells, minlength=n_prototypes * n_classes).view(n_prototypes, n_classes)


def cell_sums(columns: Tensor, region: Tensor, y: Tensor, n_prototypes: int, n_classes: int) -> Tensor:
    """Sum of the patterns of every cell V_ij, shape (P·C, d), row ``i·C + j``.

    Takes the patterns as ``columns`` = ``X.T`` made contiguous (d, N): one weighted ``bincount`` per
    dimension measured about 2× faster than ``index_add_`` of the rows on CPU.

    >>> X = torch.tensor([[1.0], [3.0], [5.0]], dtype=torch.float64)
    >>> cell_sums(X.T.contiguous(), torch.tensor([0, 0, 0]), torch.tensor([1, 1, 0]), 1, 2).flatten().tolist()
    [5.0, 4.0]
    """
    cells = region * n_classes + y
    n_cells = n_prototypes * n_classes
    return torch.stack([torch.bincount(cells, weights=column, minlength=n_cells) for column in columns], dim=1)


def quality(V: Tensor, labels: Tensor, class_sizes: Tensor) -> Tensor:
    """Quality ``q_i = min(1, accuracy_i · apportation_i)`` of every prototype [KEEL].

    ``accuracy_i = |V_{i,s_i}| / |R_i|``; ``apportation_i = |V_{i,s_i}| / (E_{s_i} / 2)`` with
    ``E_j = |S_j| / regions(j)`` and ``regions(j)`` the number of PROTOTYPES labelled j. (KEEL divides by the
    number of patterns of the class instead, which makes E ≡ 1; the spec corrects it.) An empty region, or a
    label with no training patterns, gives q = 0.

    A pure prototype holding exactly the expected number of patterns of its class has quality 1:

    >>> quality(torch.tensor([[10, 0], [0, 10]]), torch.tensor([0, 1]), torch.tensor([10, 10])).tolist()
    [1.0, 1.0]
    """
    f64 = torch.float64
    region_sizes = V.sum(dim=1).to(f64)
    own = V.gather(1, labels[:, None]).squeeze(1).to(f64)
    regions_per_class = torch.bincount(labels, minlength=V.shape[1]).to(f64)
    accuracy = own / region_sizes.clamp(min=1.0)
    own_class_size = class_sizes[labels].to(f64)
    apportation = 2.0 * own * regions_per_class[labels] / own_class_size.clamp(min=1.0)
    return (accuracy * apportation).clamp(max=1.0)


def relabel(V: Tensor, labels: Tensor) -> Tensor:
    """Labeling operator: each prototype takes the majority class of its region [paper][KEEL].

    On a tie that includes the current label, the current label is kept [spec]; among other tied classes
    the lowest class index wins. An empty region keeps its label.

    >>> relabel(torch.tensor([[1, 3], [2, 2], [0, 0]]), torch.tensor([0, 1, 1])).tolist()
    [1, 1, 1]
    """
    best_count, best_class = V.max(dim=1)
    current = V.gather(1, labels[:, None]).squeeze(1)
    return torch.where(current == best_count, labels, best_class)


def reproduce(X: Tensor, region: Tensor, y: Tensor, V: Tensor, labels: Tensor, u: Tensor) -> tuple[Tensor, Tensor]:
    """Reproduction operator [KEEL]: at most one child per prototype.

    Prototype i draws class j with probability ``|V_ij| / |R_i|`` (roulette over its row of V, driven by the
    uniform draw ``u[i]``), so it reproduces with probability ``1 − accuracy_i``. When ``j ≠ s_i`` a child is
    created at the centroid of V_ij with label j. KEEL also hands V_ij to the child, but the estimator
    re-assigns all regions right after reproduction, so the hand-over has no effect and is not modelled.
    Empty regions do not reproduce. Only the patterns of the drawn cells are summed.

    Returns ``(child_positions (K, d), child_labels (K,))``, children ordered by parent index.

    A 50/50 region labelled 0 whose draw lands in the second half creates a child at the centroid of class 1:

    >>> X = torch.tensor([[0.0, 0.0], [1.0, 1.0], [4.0, 2.0], [6.0, 2.0]], dtype=torch.float64)
    >>> region, y = torch.zeros(4, dtype=torch.int64), torch.tensor([0, 0, 1, 1])
    >>> V = contingency(region, y, 1, 2)
    >>> pos, lab = reproduce(X, region, y, V, torch.tensor([0]), torch.tensor([0.75], dtype=torch.float64))
    >>> pos.tolist(), lab.tolist()
    ([[5.0, 2.0]], [1])
    """
    n_proto, n_classes = V.shape
    region_sizes = V.sum(dim=1)
    # Integer roulette: target t in [0, |R_i| − 1]; the first class whose cumulative count exceeds t has
    # V_ij > 0 by construction, whatever the rounding of u·|R_i|.
    target = torch.minimum((u.to(torch.float64) * region_sizes).long(), (region_sizes - 1).clamp(min=0))
    drawn = torch.searchsorted(V.cumsum(dim=1), target[:, None], right=True).squeeze(1)
    drawn = drawn.clamp(max=n_classes - 1)
    reproduces = (region_sizes > 0) & (drawn != labels)
    parents = torch.nonzero(reproduces).squeeze(1)
    child_labels = drawn[parents]
    if parents.numel() == 0:
        return X.new_zeros((0, X.shape[1])), child_labels
    # Child slot of each parent (−1: none); a pattern belongs to a child's cell when its region's parent
    # drew the pattern's class.
    slot = torch.full((n_proto,), -1, dtype=torch.int64, device=V.device)
    slot[parents] = torch.arange(parents.numel(), device=V.device)
    wanted = torch.full((n_proto,), -1, dtype=torch.int64, device=V.device)
    wanted[parents] = child_labels
    rows = torch.nonzero(wanted.index_select(0, region) == y).squeeze(1)
    child_of_row = slot.index_select(0, region.index_select(0, rows))
    sums = X.new_zeros((parents.numel(), X.shape[1])).index_add_(0, child_of_row, X.index_select(0, rows))
    counts = V[parents, child_labels].to(X.dtype)
    return sums / counts[:, None], child_labels


# Over 60 lines: the fight operator's per-cell loop, one numba pass.
def fight(
    prototypes: Tensor,
    labels: Tensor,
    q: Tensor,
    k_fight: int,
    u_fight: Tensor,
    u_win: Tensor,
    n_classes: int,
) -> Tensor:
    """Fight operator [KEEL + choice]; returns the owner of every cell V_rj after the fights, shape (P·C,).

    Each prototype i looks at its ``k_fight`` nearest other prototypes and picks the neighbour j with
    ``q_j < q_i`` that maximises ``q_i − q_j`` (the nearer one on equal gaps). It fights when ``u_fight[i] < q_i − q_j``
    [choice: KEEL's test never fires because of a random-number bug].

    - Different labels → cooperation: i takes V_{j,s_i} (j's patterns of i's class).
    - Same label → competition: i wins when ``u_win[i] · (q_i + q_j) < q_i`` (probability
      ``q_i / (q_i + q_j)``); the winner takes the loser's patterns of their common class.

    In both cases a fight moves the cell (loser, winner's label) to the winner. KEEL runs the fights one after
    another, so a transfer can pass on what the loser gained earlier in the same loop; here all fights are
    decided at once on the regions as they stand [choice]: every cell starts with its region's prototype and
    a cell claimed by several winners goes to the winner of highest quality (then lowest index). Transfers
    only change what :func:`move` averages over.

    Prototype 0 (label 0, q = 1) cooperates with its neighbour 1 (label 1, q = 0) and takes cell (1, 0):

    >>> protos = torch.tensor([[0.0], [1.0]], dtype=torch.float64)
    >>> q = torch.tensor([1.0, 0.0], dtype=torch.float64)
    >>> zeros = torch.zeros(2, dtype=torch.float64)
    >>> fight(protos, torch.tensor([0, 1]), q, 3, zeros, zeros, 2).view(2, 2).tolist()
    [[0, 0], [0, 1]]
    """
    n_proto = prototypes.shape[0]
    owner = torch.arange(n_proto, device=prototypes.device).repeat_interleave(n_classes)
    k = min(k_fight, n_proto - 1)
    if k <= 0:
        return owner
    neighbours = nearest_neighbours(prototypes, k)
    gap = q[:, None] - q[neighbours]
    best_gap, best = gap.max(dim=1)
    target = neighbours.gather(1, best[:, None]).squeeze(1)
    fights = (best_gap > 0) & (u_fight < best_gap)
    attacker = torch.nonzero(fights).squeeze(1)
    if attacker.numel() == 0:
        return owner
    defender = target[attacker]
    q_att, q_def = q[attacker], q[defender]
    attacker_wins = (labels[attacker] != labels[defender]) | (u_win[attacker] * (q_att + q_def) < q_att)
    winner = torch.where(attacker_wins, attacker, defender)
    loser = torch.where(attacker_wins, defender, attacker)
    cells = loser * n_classes + labels[attacker]
    # Rank claims by (quality desc, index asc); the best-ranked claim of each cell wins it.
    by_index = torch.argsort(winner, stable=True)
    order = by_index[torch.argsort(-q[winner[by_index]], stable=True)]
    rank = torch.empty_like(order)
    rank[order] = torch.arange(order.numel(), device=order.device)
    best_rank = torch.full((n_proto * n_classes,), order.numel(), dtype=rank.dtype, device=rank.device)
    best_rank.scatter_reduce_(0, cells, rank, reduce="amin")
    claimed = best_rank < order.numel()
    owner[claimed] = winner[order[best_rank[claimed]]]
    return owner


def move(prototypes: Tensor, labels: Tensor, V: Tensor, sums: Tensor, owner: Tensor) -> Tensor:
    """Move operator [paper][KEEL]: each prototype goes to the centroid of the patterns it now represents
    with its own label (the cells it owns whose class is its label); with none it stays put.

    >>> protos = torch.tensor([[0.0], [9.0]], dtype=torch.float64)
    >>> V = torch.tensor([[2, 0], [1, 1]])
    >>> sums = torch.tensor([[2.0], [0.0], [7.0], [9.0]], dtype=torch.float64)
    >>> move(protos, torch.tensor([0, 1]), V, sums, torch.tensor([0, 0, 0, 1])).flatten().tolist()
    [3.0, 9.0]
    """
    n_proto, n_classes = V.shape
    cell_class = torch.arange(n_classes, device=V.device).repeat(n_proto)
    counts = V.reshape(-1)
    used = (counts > 0) & (cell_class == labels[owner])
    to = owner[used]
    total = torch.zeros_like(prototypes).index_add_(0, to, sums[used])
    n = torch.zeros(n_proto, dtype=prototypes.dtype, device=prototypes.device)
    n.index_add_(0, to, counts[used].to(prototypes.dtype))
    return torch.where(n[:, None] > 0, total / n.clamp(min=1.0)[:, None], prototypes)


def die(q: Tensor, u: Tensor) -> Tensor:
    """Die operator [KEEL]: keep-mask (P,) bool; prototype i dies when ``u[i] < P_die(i)``,
    ``P_die = 0 if q > 0.5 else 1 − 2q`` ("inversely proportional to quality" [paper]).

    The classifier never loses its last prototype [choice]: when every prototype would die, the one of
    highest quality (then lowest index) survives.

    >>> die(torch.tensor([0.0, 0.9, 0.0]), torch.tensor([0.5, 0.5, 0.5])).tolist()
    [False, True, False]
    >>> die(torch.tensor([0.0, 0.0]), torch.tensor([0.5, 0.5])).tolist()
    [True, False]
    """
    p_die = torch.where(q > 0.5, torch.zeros_like(q), 1.0 - 2.0 * q)
    keep = u >= p_die
    if not bool(keep.any()):
        keep[int(torch.argmax(q))] = True
    return keep
