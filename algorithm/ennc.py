"""ENNC — Evolutionary design of Nearest prototype Classifiers (a.k.a. ENPC), a scikit-learn estimator.

A 1-nearest-prototype classifier whose only essential parameter is the number of cycles [paper]. It starts from
ONE prototype and runs ``n_cycles`` cycles of six operators, in this order [paper][KEEL]: information gathering
→ labeling → reproduction → fight → move → die (see :mod:`algorithm._ennc_ops` for each operator and its
provenance tags). The number of prototypes is not given: it settles where the prototypes' quality does.

Targets are class labels, as for any scikit-learn classifier (integers, strings, integer-valued floats); a
continuous target is refused. ENNC-QL's Q values are continuous: :func:`algorithm.phase1.phase1` turns them into
at most ``max_classes`` classes, fits on the class indices and maps each prototype's class back to its Q value.
The prototypes also serve as a discretization of the input space (:meth:`ENNC.predict_index`).

:class:`ENNC` is a real scikit-learn estimator (``ClassifierMixin, BaseEstimator``, passing every check of
``sklearn.utils.estimator_checks.check_estimator``) so that the tools built on that contract work on it
unchanged: ``clone``, ``Pipeline`` (scaling the states before the fit), ``cross_val_score`` and
``GridSearchCV`` over ``n_cycles`` or ``k_fight``.

Cost: a cycle is dominated by region assignment, O(N·P·d). The first one is a full chunked GEMM pass; later
cycles only re-examine patterns that the last move, die or reproduction can have re-assigned (centre–centre
bound, :func:`algorithm._ennc_ops.refresh_nearest`), typically a fifth of a full pass once the population settles,
and under a tenth once it holds thousands of small regions. The prototype–prototype steps (the fight's nearest
neighbours, the bound's nearest-candidate distance) are k-d tree queries, O(P·log P), so no step grows as P²:
(P, P) tables took 40 % of the cycle at 1 851 prototypes on 5 000 patterns, and ever more as P grew.

Usage::

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> X = np.vstack([rng.normal(-3, 0.5, (50, 2)), rng.normal(3, 0.5, (50, 2))])
    >>> y = np.repeat(["lost", "seen"], 50)
    >>> clf = ENNC(n_cycles=50, random_state=0).fit(X, y)
    >>> clf.score(X, y)
    1.0
    >>> sorted(set(clf.labels_.tolist()))
    ['lost', 'seen']
    >>> clf.predict_index(X[:2]).shape
    (2,)

Warm start from an earlier classifier (for instance the previous ENNC-QL iteration)::

    >>> refit = ENNC(n_cycles=10, random_state=1).fit(X, y, clf.prototypes_, clf.labels_)

In a scikit-learn pipeline, tuned by cross-validation::

    >>> from sklearn.model_selection import GridSearchCV
    >>> from sklearn.pipeline import make_pipeline
    >>> from sklearn.preprocessing import StandardScaler
    >>> pipe = make_pipeline(StandardScaler(), ENNC(n_cycles=20, random_state=0))
    >>> search = GridSearchCV(pipe, {"ennc__k_fight": [1, 3]}, cv=3).fit(X, y)
    >>> search.best_params_["ennc__k_fight"] in (1, 3)
    True

Over 400 lines: the estimator and its operators' orchestration, one class as scikit-learn wants it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from sklearn.base import BaseEstimator, ClassifierMixin
from sklearn.utils import Tags
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_array, check_is_fitted, validate_data
from torch import Tensor

from algorithm import _ennc_ops as ops

logger = logging.getLogger(__name__)

InitMode = Literal["random", "mean"]


class ENNC(ClassifierMixin, BaseEstimator):
    """Evolutionary nearest-prototype classifier.

    The constructor only stores its arguments (scikit-learn's convention: ``get_params``, ``set_params`` and
    ``clone`` read them back); they are checked at :meth:`fit`, which raises ``ValueError`` on a bad one.

    Parameters
    ----------
    n_cycles:
        Number of evolution cycles N; 250 [KEEL default]. 0 returns the initial prototypes unchanged.
    k_fight:
        How many nearest prototypes each prototype considers in the fight operator; 3 [KEEL default].
    random_state:
        Seeds the ``torch.Generator`` that drives every random decision: an int >= 0 is the seed itself, a
        ``numpy.random.RandomState`` gives one draw as the seed, ``None`` draws a fresh seed. With a seed,
        ``fit`` is deterministic on CPU; on CUDA the weighted ``bincount`` behind the centroids adds in a
        varying order, so runs may drift apart by rounding (the estimator's ``non_deterministic`` tag says so).
    device:
        Torch device of the computation, ``"cpu"`` or ``"cuda"``/``"cuda:N"``. A CUDA device that is not
        available raises ``ValueError`` at ``fit``.
    init:
        The single starting prototype when no warm start is given [paper: "a random training pattern, or the
        data mean"]: ``"random"`` (default, as KEEL) takes a random training pattern with its class;
        ``"mean"`` takes the data mean labelled with the most frequent class (the first of ``classes_`` on a
        tie) [choice].
    newborn_grace:
        When true, a prototype created by reproduction is exempt from the die operator in the cycle of its
        birth, so it is judged only after it has moved once [choice, not in the spec nor in KEEL; default
        false = the spec]. With the spec's prototype-based expectation E_j, a child is judged on the mixed
        region it is born into; on data with about ten or more balanced classes every child then dies at
        once and the classifier stays at one prototype (measured: 25 classes, 20 000 patterns, 150
        Gaussian clusters → 1 prototype without grace, 151 with it). KEEL escapes this only through its
        E ≡ 1 bug.
    chunk_rows:
        Rows of X per distance block in region assignment; ``None`` sizes blocks at about 4 MiB on CPU and
        256 MiB on CUDA (:func:`algorithm._ennc_ops.default_chunk_rows`). Only memory and speed depend on it.
    n_threads:
        torch intra-op CPU threads while ``fit`` and ``predict_index`` run (torch's setting is process-wide;
        it is restored afterwards); ``None`` leaves it alone. Use 1 when other busy processes share the
        cores: measured on 2 busy cores, every parallel torch op then waits milliseconds for the second
        thread (a 150×20 row minimum: 7 µs on 1 thread, 2.5–7.7 ms on 2), a 100–1000× slowdown on small
        data. On idle cores the default uses them all, about 2× faster on 100 000 patterns.

    Attributes
    ----------
    prototypes_ : ndarray (P, d) float64
    labels_ : ndarray (P,), the class of each prototype, an element of ``classes_``
    n_prototypes_ : int, P
    classes_ : ndarray (C,), sorted classes seen in ``y`` and in ``init_labels``
    n_cycles_run_ : int
    n_prototypes_history_ : list[int], number of prototypes after each cycle
    n_features_in_ : int
    feature_names_in_ : ndarray (d,) of str, only when ``X`` had string column names (a DataFrame)

    Examples
    --------
    >>> X = [[0.0], [0.2], [5.0], [5.3]]
    >>> ENNC(n_cycles=5, random_state=0).fit(X, [1, 1, 0, 0]).predict([[0.1], [4.0]]).tolist()
    [1, 0]
    """

    def __init__(
        self,
        n_cycles: int = 250,
        k_fight: int = 3,
        random_state: int | np.random.RandomState | None = None,
        device: str = "cpu",
        init: InitMode = "random",
        newborn_grace: bool = False,
        chunk_rows: int | None = None,
        n_threads: int | None = None,
    ) -> None:
        self.n_cycles = n_cycles
        self.k_fight = k_fight
        self.random_state = random_state
        self.device = device
        self.init = init
        self.newborn_grace = newborn_grace
        self.chunk_rows = chunk_rows
        self.n_threads = n_threads

    def __sklearn_tags__(self) -> Tags:
        tags = super().__sklearn_tags__()
        # Seeded CUDA fits may differ by rounding (see random_state); the estimator checks then skip the
        # bit-exact comparisons of two fits.
        tags.non_deterministic = str(self.device).startswith("cuda")
        return tags

    # Over 60 lines: ENNC's cycle (information, operators, stopping) written as the algorithm reads.
    def fit(
        self,
        X: ArrayLike,
        y: ArrayLike,
        init_prototypes: ArrayLike | None = None,
        init_labels: ArrayLike | None = None,
    ) -> ENNC:
        """Evolve the prototypes on patterns ``X`` (N, d) with classes ``y`` (N,); returns ``self``.

        ``y`` holds class labels; a continuous target (non-integer floats, such as raw Q values) raises
        ``ValueError`` ("Unknown label type"), as in every scikit-learn classifier.

        ``init_prototypes`` (P0, d) replace the single starting prototype: the evolution continues from
        them. ``init_labels`` (P0,) are their classes, of the same kind as ``y`` (numbers or not), which
        need not occur in ``y``; a label is judged as given in the first cycle's quality (a prototype whose
        label is absent from its region has quality 0 and is likely to die), so stale labels are better
        left out: without ``init_labels`` each prototype starts with the majority class of its region in
        ``X`` (the first of ``classes_`` on a tie or for an empty region).
        """
        self._check_params()
        # force_writeable: torch cannot wrap a read-only array (a memmap) without a warning.
        x_np, y_np = validate_data(self, X, y, dtype=np.float64, force_writeable=True)
        check_classification_targets(y_np)
        warm = _check_warm_start(init_prototypes, init_labels, x_np.shape[1], y_np)

        classes = np.unique(y_np if warm is None or warm[1] is None else np.concatenate([y_np, warm[1]]))
        device = _resolve_device(self.device)
        gen = torch.Generator(device=device)
        seed = _seed(self.random_state)
        if seed is None:
            gen.seed()
        else:
            gen.manual_seed(seed)

        started = time.perf_counter()
        history: list[int] = []
        with _intra_op_threads(self.n_threads):
            X_t = torch.as_tensor(x_np, dtype=torch.float64, device=device)
            y_t = torch.as_tensor(np.searchsorted(classes, y_np), dtype=torch.int64, device=device)
            data = _Data(
                X_t, X_t.T.contiguous(), (X_t * X_t).sum(dim=1), y_t, torch.bincount(y_t, minlength=classes.size)
            )
            prototypes, labels = self._initial_prototypes(data, classes, warm, gen)
            pop = _Population.unassigned(prototypes, labels, x_np.shape[0])
            for _ in range(self.n_cycles):
                pop = _cycle(data, pop, gen, self)
                history.append(pop.prototypes.shape[0])
        prototypes, labels = pop.prototypes, pop.labels
        logger.debug(
            "ENNC fit: %d patterns, %d classes, %d cycles, %d prototypes, %.3f s",
            x_np.shape[0],
            classes.size,
            self.n_cycles,
            prototypes.shape[0],
            time.perf_counter() - started,
        )

        self.prototypes_ = prototypes.cpu().numpy()
        self.labels_ = classes[labels.cpu().numpy()]
        self.n_prototypes_ = int(prototypes.shape[0])
        self.classes_ = classes
        self.n_cycles_run_ = int(self.n_cycles)
        self.n_prototypes_history_ = history
        return self

    def _initial_prototypes(
        self,
        data: _Data,
        classes: NDArray[Any],
        warm: tuple[NDArray[np.float64], NDArray[Any] | None] | None,
        gen: torch.Generator,
    ) -> tuple[Tensor, Tensor]:
        X, y = data.X, data.y
        if warm is not None:
            prototypes = torch.as_tensor(warm[0], dtype=torch.float64, device=X.device)
            if warm[1] is not None:
                labels = torch.as_tensor(np.searchsorted(classes, warm[1]), dtype=torch.int64, device=X.device)
                return prototypes, labels
            region, _ = ops.nearest_prototype(X, prototypes, self.chunk_rows)
            return prototypes, ops.contingency(region, y, prototypes.shape[0], classes.size).argmax(dim=1)
        if self.init == "mean":
            return X.mean(dim=0, keepdim=True), torch.argmax(data.class_sizes).reshape(1)
        first = torch.randint(X.shape[0], (1,), generator=gen, device=X.device)
        return X[first], y[first]

    def predict_index(self, X: ArrayLike) -> NDArray[np.int64]:
        """Index (into ``prototypes_``) of the nearest prototype of every row of X, int64 (N,).

        Computed in blocks of ``chunk_rows`` rows on ``device``, so memory stays bounded for any N. Exact ties
        go to the lowest index. Raises ``NotFittedError`` before :meth:`fit`.
        """
        # Named, because a fit that failed after validating X has already set n_features_in_.
        check_is_fitted(self, "prototypes_")
        x_np = validate_data(self, X, dtype=np.float64, force_writeable=True, reset=False)
        device = _resolve_device(self.device)
        with _intra_op_threads(self.n_threads):
            index, _ = ops.nearest_prototype(
                torch.as_tensor(x_np, dtype=torch.float64, device=device),
                torch.as_tensor(self.prototypes_, dtype=torch.float64, device=device),
                self.chunk_rows,
            )
        return index.cpu().numpy()

    def predict(self, X: ArrayLike) -> NDArray[Any]:
        """Class (label of the nearest prototype, an element of ``classes_``) of every row of X."""
        index = self.predict_index(X)  # first, so that an unfitted ENNC raises NotFittedError
        return self.labels_[index]

    def _check_params(self) -> None:
        _check_int("n_cycles", self.n_cycles, 0)
        _check_int("k_fight", self.k_fight, 1)
        if self.random_state is not None and not isinstance(self.random_state, np.random.RandomState):
            _check_int("random_state", self.random_state, 0)
        if self.chunk_rows is not None:
            _check_int("chunk_rows", self.chunk_rows, 1)
        if self.n_threads is not None:
            _check_int("n_threads", self.n_threads, 1)
        if self.init not in ("random", "mean"):
            raise ValueError(f"init must be 'random' or 'mean', got {self.init!r}")
        if not isinstance(self.newborn_grace, bool | np.bool_):
            raise ValueError(f"newborn_grace must be a bool, got {self.newborn_grace!r}")


@dataclass(frozen=True)
class _Data:
    """The training set on the device."""

    X: Tensor  # (N, d) float64
    columns: Tensor  # (d, N) float64, X.T contiguous (for cell_sums)
    x_sq: Tensor  # (N,) float64, ||x||²
    y: Tensor  # (N,) int64 class indices
    class_sizes: Tensor  # (C,) int64, |S_j|


@dataclass(frozen=True)
class _Population:
    """The evolving classifier between two cycles, with the region assignment it was last judged on."""

    prototypes: Tensor  # (P, d) float64
    labels: Tensor  # (P,) int64 class indices
    region: Tensor  # (N,) int64 nearest prototype of each pattern at the last assignment; P: it has died
    score: Tensor  # (N,) float64, ||c_region||² − 2·x·c_region
    moved: Tensor  # (P,) bool, prototypes whose position changed since that assignment

    @classmethod
    def unassigned(cls, prototypes: Tensor, labels: Tensor, n_patterns: int) -> _Population:
        region = torch.full((n_patterns,), prototypes.shape[0], dtype=torch.int64, device=prototypes.device)
        score = torch.zeros(n_patterns, dtype=prototypes.dtype, device=prototypes.device)
        moved = torch.zeros(prototypes.shape[0], dtype=torch.bool, device=prototypes.device)
        return cls(prototypes, labels, region, score, moved)


def _cycle(data: _Data, pop: _Population, gen: torch.Generator, params: ENNC) -> _Population:
    """One ENNC cycle: information gathering → labeling → reproduction → fight → move → die [paper][KEEL].

    Quality is computed at information gathering, before labeling, and recomputed only when reproduction
    added prototypes (after re-assigning regions and deleting prototypes left with an empty region) [KEEL];
    fight and die use the latest quality. With ``newborn_grace`` this cycle's children survive die [choice].
    """
    X, y, class_sizes = data.X, data.y, data.class_sizes
    n_classes = class_sizes.shape[0]
    chunk = params.chunk_rows
    prototypes, labels = pop.prototypes, pop.labels

    # Information gathering. Only patterns that the last move and die can have affected are re-assigned.
    region, score = ops.refresh_nearest(X, prototypes, pop.region, pop.score, pop.moved, chunk, data.x_sq)
    V = ops.contingency(region, y, prototypes.shape[0], n_classes)
    q = ops.quality(V, labels, class_sizes)
    # Labeling.
    labels = ops.relabel(V, labels)
    # Reproduction. Existing prototypes have not moved, so only distances to the children are new.
    children, child_labels = ops.reproduce(X, region, y, V, labels, _uniform(gen, prototypes.shape[0], X.device))
    newborn = torch.zeros(prototypes.shape[0] + children.shape[0], dtype=torch.bool, device=X.device)
    if children.shape[0] > 0:
        first_child = prototypes.shape[0]
        prototypes = torch.cat([prototypes, children])
        region, score = ops.nearest_among_new(X, prototypes, region, score, first_child, chunk, data.x_sq)
        newborn[first_child:] = True
        labels = torch.cat([labels, child_labels])
        V = ops.contingency(region, y, prototypes.shape[0], n_classes)
        occupied = V.sum(dim=1) > 0
        if not bool(occupied.all()):
            region = (torch.cumsum(occupied, dim=0) - 1).index_select(0, region)
            prototypes, labels, V, newborn = prototypes[occupied], labels[occupied], V[occupied], newborn[occupied]
        q = ops.quality(V, labels, class_sizes)
    sums = ops.cell_sums(data.columns, region, y, prototypes.shape[0], n_classes)
    # Fight.
    n_proto = prototypes.shape[0]
    u_fight, u_win = _uniform(gen, n_proto, X.device), _uniform(gen, n_proto, X.device)
    owner = ops.fight(prototypes, labels, q, params.k_fight, u_fight, u_win, n_classes)
    # Move.
    moved_to = ops.move(prototypes, labels, V, sums, owner)
    moved = (moved_to != prototypes).any(dim=1)
    # Die.
    keep = ops.die(q, _uniform(gen, n_proto, X.device))
    if params.newborn_grace:
        keep |= newborn
    survivors = torch.cumsum(keep, dim=0)
    new_index = torch.where(keep, survivors - 1, survivors[-1])
    return _Population(moved_to[keep], labels[keep], new_index.index_select(0, region), score, moved[keep])


@contextmanager
def _intra_op_threads(n_threads: int | None) -> Iterator[None]:
    if n_threads is None:
        yield
        return
    previous = torch.get_num_threads()
    torch.set_num_threads(int(n_threads))
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _check_int(name: str, value: object, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name} must be an int >= {minimum}, got {value!r}")


def _uniform(gen: torch.Generator, n: int, device: torch.device) -> Tensor:
    return torch.rand(n, generator=gen, dtype=torch.float64, device=device)


def _seed(random_state: int | np.random.RandomState | None) -> int | None:
    if isinstance(random_state, np.random.RandomState):
        return int(random_state.randint(2**31))
    return None if random_state is None else int(random_state)


def _check_warm_start(
    init_prototypes: ArrayLike | None, init_labels: ArrayLike | None, n_features: int, y: NDArray[Any]
) -> tuple[NDArray[np.float64], NDArray[Any] | None] | None:
    if init_prototypes is None:
        if init_labels is not None:
            raise ValueError("init_labels given without init_prototypes")
        return None
    prototypes = check_array(init_prototypes, dtype=np.float64, input_name="init_prototypes")
    if prototypes.shape[1] != n_features:
        raise ValueError(f"init_prototypes has {prototypes.shape[1]} features, X has {n_features}")
    if init_labels is None:
        return prototypes, None
    labels = check_array(init_labels, dtype=None, ensure_2d=False, input_name="init_labels")
    if labels.shape != (prototypes.shape[0],):
        raise ValueError(f"init_labels must have shape ({prototypes.shape[0]},), got {labels.shape}")
    check_classification_targets(labels)
    # Concatenating numbers with strings would silently turn every class into a string.
    if np.issubdtype(labels.dtype, np.number) != np.issubdtype(y.dtype, np.number):
        raise ValueError(f"init_labels ({labels.dtype}) and y ({y.dtype}) must both be numeric or both not")
    return prototypes, labels


def _resolve_device(device: str) -> torch.device:
    resolved = torch.device(device)
    if resolved.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} requested but CUDA is not available; use device='cpu'")
    if resolved.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda[:N]', got {device!r}")
    return resolved
