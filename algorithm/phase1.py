"""ENNC-QL phase 1: fitted iterations with one ENNC classifier per action [paper §2.2].

Iteration t builds, for each action a, the training set T_a = {⟨s, q⟩} from the tuples with action a, where
q = r + γ·max_b Q̂_b^(t−1)(s′) (q = r for terminal s′), turns the q values into classes (:func:`to_classes`) and
fits an ENNC on their class indices; the label of each prototype is the Q value of its class and its prototypes
are the discretization S_a. Q̂^(0) ≡ 0.

Usage::

    result = phase1(transitions, n_actions=8, config=Phase1Config(max_iterations=1), seed=0)
    result.discretization          # per-action prototypes + Q-value labels
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import numpy as np

from algorithm.discretization import Discretization
from algorithm.transitions import Transitions

if TYPE_CHECKING:
    from algorithm.ennc import ENNC

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Phase1Config:
    """Parameters of phase 1; every [choice] of the spec is here with its default."""

    n_cycles: int = 250
    """ENNC cycles per fit [KEEL default]."""
    k_fight: int = 3
    """Neighbours a prototype may fight [KEEL default]."""
    gamma: float = 0.9
    """Discount of the Q targets [choice]."""
    max_iterations: int = 20
    """K_max: stop after this many iterations at most [choice]; CMOMMT needs one [paper]."""
    max_classes: int = 32
    """C_max: more distinct q values than this are quantized into C_max bins [choice]."""
    round_to: float = 1e-6
    """q values are rounded to this step before counting distinct classes [choice]."""
    quantizer: Literal["quantile", "uniform"] = "quantile"
    """How q values are binned when there are too many: equal-count or equal-width bins [choice]."""
    max_patterns: int | None = None
    """Fit each action's ENNC on at most this many tuples (a uniform sample); None = all [choice]."""
    targets: Literal["reward", "lost"] = "reward"
    """What ENNC's classes are drawn from: ``reward``, q = r + γ·max_b Q̂(s′, b) [paper]; ``lost``, the same with r
    replaced by the lost reward where the tuple ended its robot's trial by losing every target (a terminal s′ in
    which the featurizer sees no target: :attr:`sim.features.Featurizer.sees_none`) and by 0 elsewhere [beyond the
    paper: a per-decision reward gives noisy, many-valued targets on which ENNC keeps few prototypes; the lost signal
    is the crisp one the paper's delayed reward gives, while phase 2 learns the reward itself]."""
    seed_prototypes: int = 0
    """0: each ENNC starts from one prototype [paper]. P > 0: from P of the action's training states (a uniform
    sample), each with the majority class of its region, so that the discretization starts as fine as P cells spread
    with the states and ENNC refines it where the classes mix [beyond the paper: the class boundaries alone leave
    the rest of the space in a few large cells]."""
    cells: Literal["per-action", "union"] = "per-action"
    """``per-action``: each action's cells are its own ENNC's prototypes [paper]. ``union``: every action's cells
    are the prototypes of every action's ENNC, each labelled with that action's Q̂ at it [beyond the paper]."""
    device: str = "cpu"
    """torch device of the ENNC operators."""
    standardize: bool = True
    """Fit ENNC on states scaled to unit variance per dimension, and keep that scale as the discretization's
    metric [choice]. The (1000, 1000) mask makes the 6-D states bimodal (a robot in view or not, ~1400 apart);
    on raw states ENNC measured 1–6 prototypes per action and never separated the lost regions, on standardized
    ones ≈170 (the paper reports ≈184)."""

    def __post_init__(self) -> None:
        if self.n_cycles < 1 or self.max_iterations < 1 or self.max_classes < 2 or self.k_fight < 1:
            raise ValueError("n_cycles, max_iterations, k_fight must be >= 1 and max_classes >= 2")
        if not 0.0 <= self.gamma < 1.0:
            raise ValueError(f"gamma must lie in [0, 1), got {self.gamma}")
        if self.round_to <= 0:
            raise ValueError("round_to must be positive")
        if self.max_patterns is not None and self.max_patterns < 1:
            raise ValueError("max_patterns must be positive or None")
        if self.targets not in ("reward", "lost"):
            raise ValueError(f"targets must be 'reward' or 'lost', got {self.targets!r}")
        if self.cells not in ("per-action", "union"):
            raise ValueError(f"cells must be 'per-action' or 'union', got {self.cells!r}")
        if self.seed_prototypes < 0:
            raise ValueError("seed_prototypes must be non-negative")


CMOMMT_PHASE1 = Phase1Config(max_iterations=1, max_patterns=30_000)
"""Phase 1 as this project fits it on CMOMMT: the learner's default, reproduce's full budget and the actor benchmark's
policy. One fitted iteration suffices in CMOMMT [paper]; 30 000 tuples per action keep a fit under a minute here."""


@dataclass(frozen=True, slots=True)
class Phase1Result:
    discretization: Discretization
    iterations: int
    """Iterations run."""
    converged: bool
    """No training state's predicted value changed in the last iteration."""
    changed: list[float] = field(default_factory=list)
    """Fraction of training states whose predicted value changed, per iteration."""


def to_classes(q: np.ndarray, config: Phase1Config) -> np.ndarray:
    """Map continuous targets to at most ``max_classes`` class values (each class labelled by a value of q).

    Distinct values after rounding are kept when there are few enough; otherwise q is binned (quantiles or equal
    width) and every bin is labelled by the mean q of its members [choice].
    """
    q = np.asarray(q, dtype=np.float64)
    rounded = np.round(q / config.round_to) * config.round_to
    values = np.unique(rounded)
    if values.size <= config.max_classes:
        return rounded
    if config.quantizer == "quantile":
        edges = np.unique(np.quantile(q, np.linspace(0.0, 1.0, config.max_classes + 1)))
    else:
        edges = np.linspace(q.min(), q.max(), config.max_classes + 1)
    bins = np.clip(np.searchsorted(edges, q, side="right") - 1, 0, edges.size - 2)
    means = np.bincount(bins, weights=q, minlength=edges.size - 1) / np.maximum(
        np.bincount(bins, minlength=edges.size - 1), 1
    )
    return np.round(means[bins] / config.round_to) * config.round_to


def _constant(states: np.ndarray, n_actions: int, scale: np.ndarray | None) -> Discretization:
    """Q̂^(0): one prototype per action, labelled 0 [paper]."""
    centre = states.mean(axis=0, keepdims=True)
    return Discretization.from_per_action([centre] * n_actions, scale=scale)


def standard_scale(states: np.ndarray) -> np.ndarray:
    """(d,) per-dimension standard deviation, with constant dimensions kept at 1."""
    std = np.asarray(states, dtype=np.float64).std(axis=0)
    return np.where(std > 1e-9, std, 1.0).astype(np.float32)


Progress = Callable[[int, int], None]


def estimator() -> type[ENNC]:
    """The ENNC class, imported on first use: ``Phase1Config`` is read by processes that never fit and must not load
    torch; a process that will fit calls this early so its first fit does not wait for torch and scikit-learn."""
    from algorithm.ennc import ENNC

    return ENNC


def _fit_action(
    ennc_class: type[ENNC],
    config: Phase1Config,
    rng: np.random.Generator,
    states: np.ndarray,
    q: np.ndarray,
    warm: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """One action's ENNC on its (standardized) training ``states`` and targets ``q``: its prototypes (standardized)
    and their Q-value labels.

    ``warm`` (first iteration of a warm start only): the action's warm prototypes (standardized), their labels, and
    the Q values learned over them (or None); without seeds the fit starts from those prototypes, labelled with the
    class nearest their learned value, or else with their own labels among the classes.
    """
    model = ennc_class(
        n_cycles=config.n_cycles,
        k_fight=config.k_fight,
        random_state=int(rng.integers(2**31)),
        device=config.device,
    )
    classes = to_classes(q, config)
    # ENNC refuses continuous targets, so it fits on class indices, numbered in the order of the Q values so that
    # its ties (first class wins) still fall on the lowest Q value.
    if config.seed_prototypes > 0:
        q_values, index = np.unique(classes, return_inverse=True)
        start = rng.choice(len(q), min(config.seed_prototypes, len(q)), replace=False)
        model.fit(states, index, init_prototypes=states[np.sort(start)])
    elif warm is not None and warm[2] is not None:
        prototypes, _, learned = warm
        q_values, index = np.unique(classes, return_inverse=True)
        nearest = np.abs(np.asarray(learned, np.float64)[:, None] - q_values[None, :]).argmin(axis=1)
        model.fit(states, index, init_prototypes=prototypes, init_labels=nearest)
    elif warm is not None:
        prototypes, warm_labels, _ = warm
        q_values, index = np.unique(np.concatenate([classes, warm_labels]), return_inverse=True)
        model.fit(states, index[: len(q)], init_prototypes=prototypes, init_labels=index[len(q) :])
    else:
        q_values, index = np.unique(classes, return_inverse=True)
        model.fit(states, index)
    return model.prototypes_, q_values[model.labels_]


def phase1(
    data: Transitions,
    n_actions: int,
    config: Phase1Config | None = None,
    seed: int | None = None,
    warm_start: Discretization | None = None,
    progress: Progress | None = None,
    values: np.ndarray | None = None,
    lost: np.ndarray | None = None,
    lost_reward: float = -1.0,
) -> Phase1Result:
    """Fitted ENNC iterations until no predicted value changes or ``max_iterations``.

    ``warm_start`` seeds every action's first fit with its prototypes and labels (the learner's refits as data
    grows; with ``seed_prototypes`` the fits start from seeds instead, and the warm start gives only its scale and
    values). ``values`` (Σ P_a,), with ``warm_start``: Q values learned over its cells (phase 2's tables); the
    first iteration's targets then bootstrap from them instead of from Q̂^(0) ≡ 0, and each warm prototype starts
    labelled with the class nearest its value. ``lost`` (N,) bool, needed by ``targets="lost"``: the tuples whose s′
    sees no target (the featurizer's :attr:`~sim.features.Featurizer.sees_none` of ``data.next_state``); the
    terminal ones among them get the scenario's ``lost_reward`` as their reward. ``progress(iteration, action)`` is
    called after each fit.
    """
    ennc_class = estimator()
    config = config or Phase1Config()
    if len(data) == 0:
        raise ValueError("phase 1 needs at least one tuple")
    rng = np.random.default_rng(seed)
    states = np.asarray(data.state, dtype=np.float64)
    next_states = np.asarray(data.next_state, dtype=np.float64)
    actions = np.asarray(data.action, dtype=np.int64)
    if actions.max() >= n_actions:
        raise ValueError(f"tuples name action {actions.max()} but there are only {n_actions} actions")
    rewards = np.asarray(data.reward, dtype=np.float64)
    if config.targets == "lost":
        if lost is None or np.shape(lost) != (len(data),):
            raise ValueError("targets='lost' needs lost: whether each tuple's s' sees no target")
        rewards = np.where(data.done & lost, lost_reward, 0.0)
    scale = warm_start.scale if warm_start is not None else standard_scale(states) if config.standardize else None
    unit = np.ones(states.shape[1]) if scale is None else scale.astype(np.float64)
    if values is not None:
        if warm_start is None or np.shape(values) != (warm_start.size,):
            raise ValueError("values need a warm start and one value per cell of it")
        disc = dataclasses.replace(warm_start, labels=np.asarray(values, np.float32))
    else:
        disc = _constant(states, n_actions, scale)
    predicted = np.zeros(len(data))
    changed: list[float] = []
    converged = False
    for it in range(1, config.max_iterations + 1):
        bootstrap = disc.labels[disc.cells(next_states)].max(axis=1)
        q = np.where(data.done, rewards, rewards + config.gamma * bootstrap)
        protos: list[np.ndarray] = []
        labels: list[np.ndarray] = []
        for a in range(n_actions):
            rows = np.nonzero(actions == a)[0]
            if rows.size == 0:
                protos.append(disc.action_prototypes(a))
                labels.append(disc.labels[disc.offsets[a] : disc.offsets[a + 1]])
                continue
            if config.max_patterns is not None and rows.size > config.max_patterns:
                rows = np.sort(rng.choice(rows, config.max_patterns, replace=False))
            warm = None
            if warm_start is not None and it == 1:
                lo, hi = warm_start.offsets[a], warm_start.offsets[a + 1]
                learned = None if values is None else values[lo:hi]
                warm = (warm_start.prototypes[lo:hi] / unit, warm_start.labels[lo:hi], learned)
            prototypes, action_labels = _fit_action(ennc_class, config, rng, states[rows] / unit, q[rows], warm)
            protos.append(prototypes * unit)
            labels.append(action_labels)
            log.debug("phase 1 iteration %d action %d: %d prototypes", it, a, len(prototypes))
            if progress is not None:
                progress(it, a)
        disc = Discretization.from_per_action(protos, labels, scale=scale)
        cells = disc.cells(states)
        new_predicted = disc.labels[cells[np.arange(len(data)), actions]].astype(np.float64)
        frac = float(np.mean(np.abs(new_predicted - predicted) > config.round_to / 2))
        changed.append(frac)
        predicted = new_predicted
        log.info("phase 1 iteration %d: %d prototypes, %.2f%% predictions changed", it, disc.size, 100 * frac)
        if frac == 0.0:
            converged = True
            break
    if config.cells == "union":
        disc = united(disc)
    return Phase1Result(discretization=disc, iterations=len(changed), converged=converged, changed=changed)


def united(disc: Discretization) -> Discretization:
    """Every action's cells made the union of all actions' prototypes, each labelled with the action's own Q̂ there
    (the label of the action's nearest prototype, so an action keeps its labels at its own prototypes).

    A prototype that several actions share (a warm start without seeds starts every action from the same union, and
    a prototype no pattern moves stays where it was) is kept once, where it first occurs."""
    _, first = np.unique(disc.prototypes, axis=0, return_index=True)
    union = disc.prototypes[np.sort(first)]
    cells = disc.cells(union)
    labels = [disc.labels[cells[:, a]] for a in range(disc.n_actions)]
    return Discretization.from_per_action([union] * disc.n_actions, labels, scale=disc.scale)
