"""The learner process's configuration: every default of ``ennc-ql learner`` is written here, once.

The command's flags are generated from these fields (their docstrings are the ``--help`` text), ``--config FILE``
reads the same fields from TOML, and ``ennc-ql up`` builds one of these instead of a command line.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from algorithm.checks import require_at_least, require_id, require_known, require_positive
from algorithm.phase1 import CMOMMT_PHASE1, Phase1Config
from sim import SCENARIOS
from sim.controllers import HAND_MADE
from sim.formulation import DEFAULT_FORMULATION, Formulation, resolve_formulation

LEARNER_PHASE1 = dataclasses.replace(CMOMMT_PHASE1, max_iterations=2, n_cycles=60, seed_prototypes=512, cells="union")
"""The learner's phase 1 [beyond the paper, README "Learning quality"]: ENNC starts from 512 of each action's
training states and runs 60 cycles (one prototype and 250 cycles [paper] leave a per-decision reward's noisy classes
in a few cells, and 250 cycles from 512 states grow thousands of prototypes the actors must search), two fitted
iterations (a second one measured +1 to +3 points), and every action's cells are the union of all actions'
prototypes (docs/learning-quality.md, "Eleventh round"). ``ennc-ql reproduce`` keeps the paper's."""


@dataclass(frozen=True, slots=True)
class LearnerConfig:
    learner_id: str = "learner"
    """Learner id (a key-expression chunk: letters, digits, '_', '.', '-')."""
    scenario: str = "cmommt-v1"
    """Scenario the policy is learned and evaluated on."""
    formulation: str = DEFAULT_FORMULATION
    """State, reward and action set of the experience, and how often the evaluated policy decides, by name (see
    README "Formulation"; paper is the paper's). The actors' must be the same."""
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
    """Tuples kept; the oldest are overwritten beyond it (counted)."""
    min_tuples: int = 150_000
    """Tuples stored before the first phase 1."""
    refit_growth: float = 0.0
    """Refit (warm-started) whenever the tuples received have grown this many times since the last fit; 0 = never."""
    phase1: Phase1Config = field(default_factory=lambda: LEARNER_PHASE1)
    """ENNC-QL phase 1."""
    broadcast_interval: float = 3.0
    """Seconds between merges + policy broadcasts."""
    team_policy: bool = True
    """Evaluate and save the policy with one table every robot uses, the actors' per-robot tables merged by their
    visits (docs/learning-quality.md, "the learner's merge across robots"); the broadcast keeps each robot's own
    table, so the actors learn on option 2 either way. Off: each robot acts on its own row, as the paper's option 2
    [paper]."""
    eval_interval: float = 20.0
    """Seconds between evaluations of the current policy."""
    eval_trials: int = 10
    """Test trials of the periodic evaluations (the learning curve), as the paper scores one process [paper]."""
    final_eval_trials: int = 200
    """Test trials of the final policy's figure and of its paired comparison with every reference: 200, since one
    run of ten trials varies by a few points from one set of trials to another, and a paired difference of a point
    needs about 200 trials for a standard error near 0.5 [choice; the paper's figures rest on 5 x 10]."""
    keep_best: bool = True
    """Save, score and report the policy that scored best on the validation trials (``validation_trials`` of seed
    1000, never the reported test trials) at the periodic evaluations and at the end, rather than the last one:
    phase 2 can settle on a worse policy and stay there [beyond the paper]. The actors learn on the current tables
    either way. Off: the last policy."""
    validation_trials: int = 30
    """Validation trials of each periodic evaluation when ``keep_best`` (the same trials every time)."""
    early_window: float = 10.0
    """With ``keep_best``: every policy version published within this many seconds of the first is scored on the
    validation trials, and the best of them is a second candidate beside the kept policy. It is scored on
    ``margin_trials`` validation trials when the window closes (a law action set's read with the margin that scores
    best, or with ``law_margin``), the kept policy at the end of the run, and the better is saved. Phase 2's first
    seconds can hold tables that more experience loses [beyond the paper, docs/learning-quality.md "Twentieth
    round"]. 10 s: a draw's tables are made by its second version, about 3 s into phase 2, and the later versions
    of a 30-s window differed by the noise of their scores only, so a shorter window leaves time for more draws
    [choice, docs/learning-quality.md "Twenty-fourth round"]. 0: no early candidate."""
    early_trials: int = 150
    """Validation trials on which each version of an early window is scored: 30 told ten versions apart by little
    more than noise (a version's 30-trial scores spread over 2–3 points within one window) [choice,
    docs/learning-quality.md "Twenty-third round"]."""
    early_margin: float = 0.5
    """With a law action set whose margin the run chooses (``law_margin`` none): the law margin with which an early
    window's versions are read when they are scored, so that they are ranked about as they will be read; the
    candidate's own margin is chosen once its window closes (a ``law_margin`` given reads them with that one). 0.5
    read the forty-five candidates of the twenty-third round's runs best on average on the validation trials
    [choice, docs/learning-quality.md "Twenty-third round"]."""
    draws: int = 24
    """With ``keep_best`` and ``early_window``: independent draws of phase 1. When a draw's early window has closed
    and its candidate is scored, phase 1 runs afresh (a new seed, no warm start) on the first fit's tuples, the
    exploration before any policy (kept in the run folder's ``exploration.npz``), and the actors start again from
    its cells, with tables from its labels; each draw has its own early window, and the early candidate that scores
    best on ``margin_trials`` validation trials over the draws is the one beside the kept policy at the end. A draw
    starts only when its window can close before ``duration`` (judged by the last fit's seconds), so a short run
    makes fewer (an 8-minute run on a 2-core machine makes 13, about 37 s each). Runs differ by a point from one
    phase-1 draw to the next, and the validation trials tell the better ones [beyond the paper,
    docs/learning-quality.md "Twenty-second round"]; 24 bounds a long run's draws, after which phase 2 goes on in
    the last draw's cells [choice]. 1: the first fit only."""
    law_margin: float | None = None
    """With a law action set (the default formulation's): the saved and scored policy departs from the move law
    only where another move's value beats law's by more than this (0: the plain argmax); none: the margin of
    algorithm.selection.LAW_MARGINS that scores best on margin_trials validation trials of seed 1000, chosen at the
    end of the run [beyond the paper, docs/learning-quality.md "Eighteenth round"]. Other action sets: the argmax."""
    margin_trials: int = 300
    """Validation trials on which each margin is scored when law_margin is none."""
    spread_cap: str | None = "a-cmommt"
    """The hand-made controller whose spread over the targets holds the run's choices: a law margin, a draw's
    candidate or the saved policy whose team has more robots per covered target on the ``margin_trials`` validation
    trials than this controller's team there is chosen only where none has fewer, so the learned team covers more
    without crowding the targets more than the law [beyond the paper, docs/learning-quality.md "Twenty-sixth round"].
    none: coverage alone, which in five runs of each covered 0.4 points more on the reported trials (+1.40 against
    +0.99 over a-cmommt) at 1.071–1.093 robots per covered target, where the cap's runs stood at 1.057–1.059 and
    a-cmommt at 1.062."""
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
        if self.spread_cap is not None:
            require_known("spread_cap", self.spread_cap, HAND_MADE)
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
            validation_trials=self.validation_trials,
            early_trials=self.early_trials,
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
        require_at_least(1, draws=self.draws)
        if self.drawing and self.refit_growth != 0:
            raise ValueError(
                f"draws = {self.draws} and refit_growth = {self.refit_growth}: a refit would carry one draw's tables "
                "into another's cells; give draws = 1 (--draws 1) to refit"
            )
        if not (math.isfinite(self.early_window) and self.early_window >= 0):
            raise ValueError(f"early_window must be a finite number of seconds >= 0, got {self.early_window}")
        if not (math.isfinite(self.early_margin) and self.early_margin >= 0):
            raise ValueError(f"early_margin must be a finite number >= 0, got {self.early_margin}")
        if self.law_margin is not None and not (math.isfinite(self.law_margin) and self.law_margin >= 0):
            raise ValueError(f"law_margin must be none or a finite number >= 0, got {self.law_margin}")
        if self.refit_growth != 0 and not self.refit_growth > 1:
            raise ValueError(f"refit_growth must be 0 (never) or above 1, got {self.refit_growth}")

    @property
    def drawing(self) -> bool:
        """Whether the run makes more than one draw of phase 1 (``draws`` needs an early candidate to choose by)."""
        return self.draws > 1 and self.keep_best and self.early_window > 0

    @property
    def method(self) -> str:
        """The name the learned policy carries (as in ``reproduce``'s table)."""
        return "ennc-ql-local" if self.resolved.featurizer.name == "local2d" else "ennc-ql-collab-option2"
