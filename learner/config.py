"""The learner process's configuration: every default of ``ennc-ql learner`` is written here, once.

The command's flags are generated from these fields (their docstrings are the ``--help`` text), ``--config FILE``
reads the same fields from TOML, and ``ennc-ql up`` builds one of these instead of a command line.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from algorithm.checks import require_at_least, require_at_most, require_id, require_known, require_positive
from algorithm.phase1 import CMOMMT_PHASE1, Phase1Config
from sim import SCENARIOS
from sim.formulation import DEFAULT_FORMULATION, Formulation, resolve_formulation
from sim.world import MAX_ARENAS

LEARNER_PHASE1 = dataclasses.replace(CMOMMT_PHASE1, max_iterations=2, n_cycles=60, seed_prototypes=512, cells="union")
"""The learner's phase 1 [beyond the paper; docs/concepts/learning.md]: ENNC starts from 512 of each action's
training states and runs 60 cycles (one prototype and 250 cycles [paper] leave a per-decision reward's noisy classes
in a few cells, and 250 cycles from 512 states grow thousands of prototypes the actors must search), two fitted
iterations (a second one measured +1 to +3 points), and every action's cells are the union of all actions'
prototypes (a rare situation otherwise fell into another situation's cells: docs/notebook.md, "2026-12-04: one set
of cells for every action"). ``ennc-ql reproduce`` keeps the paper's."""


MAX_STORE = 50_000_000
"""The largest store a learner keeps: about 160 bytes of memory per tuple of capacity (the store, a checkpoint's copy
and phase 1's pass over it; docs/performance.md), so about 8 GB; a mistyped capacity would fill memory and disk."""


@dataclass(frozen=True, slots=True)
class LearnerConfig:
    learner_id: str = "learner"
    """Learner id (a key-expression chunk: letters, digits, '_', '.', '-')."""
    scenario: str = "cmommt-v1"
    """Scenario the policy is learned and evaluated on."""
    formulation: str = DEFAULT_FORMULATION
    """State, reward and action set of the experience, and how often the evaluated policy decides, by name (see
    docs/concepts/learning.md; paper is the paper's). The actors' must be the same."""
    featurizer: str | None = None
    """State definition instead of the formulation's (none: the formulation's)."""
    reward: str | None = None
    """Reward instead of the formulation's (none: the formulation's; paper: the state's own), as the actors'
    --reward: recorded in the policy; the learner's fits read the rewards of the tuples."""
    act_every: int | None = None
    """Steps between a robot's decisions when the learned policy is evaluated and in the policy file, instead of the
    formulation's (none: the formulation's; the paper's is the scenario's action_steps, as the actors learn); the
    broadcast keeps the actors' action_steps."""
    resolved: Formulation = field(init=False, repr=False, compare=False)
    """The formulation this learner runs: ``formulation`` with the explicit fields over it (resolved here, once)."""
    store_capacity: int = 1_000_000
    """Tuples kept; the oldest are overwritten beyond it (counted). At most MAX_STORE."""
    min_tuples: int = 150_000
    """Tuples stored before the first phase 1."""
    refit_growth: float = 0.0
    """Refit (warm-started) whenever the tuples received have grown this many times since the last fit; 0 = never."""
    phase1: Phase1Config = field(default_factory=lambda: LEARNER_PHASE1)
    """ENNC-QL phase 1."""
    broadcast_interval: float = 3.0
    """Seconds between merges + policy broadcasts."""
    team_policy: bool = False
    """Save and score the policy with one table every robot uses, the actors' per-robot tables merged by their
    visits (docs/concepts/saving.md). Off (default): each robot acts on its own
    row, the paper's option 2 [paper], and the final report scores the merged team table beside it; the broadcast
    keeps each robot's own table, so the actors learn on option 2 either way."""
    eval_interval: float = 20.0
    """Seconds between evaluations of the current policy."""
    eval_trials: int = 10
    """Trials of the periodic evaluations (the learning curve), as the paper scores one process [paper]: development
    trials (algorithm.selection.DEVELOPMENT_SEED), read many times a run, never the reported ones."""
    final_eval_trials: int = 200
    """Test trials (algorithm.selection.TEST_SEED) of the final policy's figure and of its paired comparison with
    every reference: 200, since one
    run of ten trials varies by a few points from one set of trials to another, and a paired difference of a point
    needs about 200 trials for a standard error near 0.5 [choice; the paper's figures rest on 5 x 10]."""
    law_margin: float | None = None
    """With a law action set (the default formulation's): the saved and scored policy departs from the move law
    only where another move's value beats law's by more than this (0: the plain argmax); none: the margin of
    algorithm.selection.LAW_MARGINS that scores best on margin_trials validation trials of seed 1000, chosen at the
    end of the run (algorithm.selection.SaveRule) [beyond the paper]. Other action sets: the argmax."""
    margin_trials: int = 300
    """Validation trials on which each margin is scored when law_margin is none."""
    eval_steps: int = 1000
    """Steps of each test trial [paper]."""
    checkpoint_interval: float = 0.5
    """Seconds between checkpoints (on a thread of their own, so an evaluation never delays one); acknowledgements
    follow each checkpoint, so an actor's outbox holds about this long of its experience (≈ 38 MB/s at ≈ 400 k tuples/s
    of 11-number states): 0.5 s keeps an actor under 300 MB (1 s: 301–306 MB over 120 s, docs/performance.md), while a
    checkpoint of a full 400 k-tuple store (44 MB) costs ≈ 0.07–0.15 s."""
    status_interval: float = 2.0
    """Seconds between status messages."""
    duration: float | None = None
    """Stop after this many seconds (None: until stopped)."""
    seed: int = 0
    """Seed of phase 1's random draws."""
    threads: int = 0
    """Torch threads for phase 1 (0: torch's choice; 1 avoids stalls on cores shared with actors)."""

    def __post_init__(self) -> None:
        require_id("learner_id", self.learner_id)
        require_known("scenario", self.scenario, SCENARIOS)
        resolved = resolve_formulation(
            self.formulation, featurizer=self.featurizer, reward=self.reward, act_every=self.act_every
        )
        object.__setattr__(self, "resolved", resolved)
        require_at_least(
            1,
            store_capacity=self.store_capacity,
            min_tuples=self.min_tuples,
            eval_trials=self.eval_trials,
            final_eval_trials=self.final_eval_trials,
            margin_trials=self.margin_trials,
            eval_steps=self.eval_steps,
        )
        require_positive(
            broadcast_interval=self.broadcast_interval,
            eval_interval=self.eval_interval,
            checkpoint_interval=self.checkpoint_interval,
            status_interval=self.status_interval,
            duration=self.duration,
        )
        require_at_least(0, threads=self.threads, seed=self.seed)
        require_at_most(MAX_STORE, store_capacity=self.store_capacity)
        # Each figure's trials run side by side, as arenas of one batch.
        require_at_most(
            MAX_ARENAS,
            eval_trials=self.eval_trials,
            final_eval_trials=self.final_eval_trials,
            margin_trials=self.margin_trials,
        )
        if self.law_margin is not None and not (math.isfinite(self.law_margin) and self.law_margin >= 0):
            raise ValueError(f"law_margin must be none or a finite number >= 0, got {self.law_margin}")
        if self.refit_growth != 0 and not self.refit_growth > 1:
            raise ValueError(f"refit_growth must be 0 (never) or above 1, got {self.refit_growth}")

    @property
    def method(self) -> str:
        """The name the learned policy carries (as in ``reproduce``'s table)."""
        return "ennc-ql-local" if self.resolved.featurizer.name == "local2d" else "ennc-ql-collab-option2"
