"""A learning problem's formulation: the parts a robot learns from, resolved from their names once.

A :class:`Formulation` holds the resolved objects, each taken from its part's registry:

* the state: a :class:`~sim.features.Featurizer` of :data:`sim.features.FEATURIZER_REGISTRY`;
* the reward: a :class:`~sim.features.Reward` of :data:`sim.features.REWARDS` (``paper``: the state's own);
* the action set: an :class:`~sim.actions.ActionSet` of :data:`sim.actions.ACTION_SETS`;
* the learning-trial rules: a :class:`TrialRules` of :data:`TRIAL_RULES`;
* how often a robot of the learned policy decides in test trials (``act_every``).

Building one from names is the only place a part's name is checked; everything below it (the trial kernel, the
experience slice, the policy, the wire, the monitor, the environment adapters) is handed the objects. A new state,
reward, action set or set of rules is an entry of its registry and nothing else::

    f = Formulation.of("shared8d", "difference", "compass", act_every=1)    # FORMULATIONS["shared-difference"]
    f = resolve_formulation("paper", reward="difference", trial_rules="search-on")  # a named one, parts over it
    f = f.replace(actions="relative")                                        # the same with one part renamed
    f.featurizer.compute(cfg, obs), f.reward.value(cfg, obs), f.actions.velocity(cfg, chosen, frame)
    f.names                  # ("collab6d", "difference", "relative"): what the wire and the policy file carry
    f.text                   # "collab6d/difference/relative/none/search-on": every part, for a job file
    f.dim, f.describe()
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeVar

from sim.actions import ACTION_SETS, ActionSet
from sim.features import FEATURIZER_REGISTRY, REWARDS, Featurizer, Reward
from sim.guide import Guide


@dataclass(frozen=True, slots=True)
class TrialRules:
    """How a learning trial treats a learner that loses every target, and the trial's time-out [paper §4, as
    tagged]. They shape learning trials only: test trials and the wire never read them."""

    name: str
    lost_ends_trial: bool = True
    """A learning robot that loses every target gets ``lost_reward``, its trial ends and it stays motionless [paper].
    False: it searches as a test-time robot does (keeps its heading, reflected off the wall) and goes on deciding and
    learning; its tuples carry the reward's own value [beyond the paper: leaving a target that a teammate already
    observes, to search for an unobserved one, is then no terminal failure]."""
    timeout_terminal: bool = True
    """The tuple a learner holds when the trial's ``learning_steps`` run out is terminal (q = r) [paper: the trial
    ends]. False: it bootstraps from its s′, as a time limit that is not part of the task should [beyond the paper;
    only with a per-decision reward, whose value is not paid at the end of the trial]."""
    continuing: bool = False
    """Learning trials follow each other in the same arenas: a trial starts where the previous one left every robot
    and target, and every ``test_steps // learning_steps`` trials the arenas start afresh as a test trial's do
    (robots and targets uniform in the disk, not beside a target). Learning then meets the states of whole test
    trials in their proportions, the late, crowded phase included, which trials that start beside a target rarely
    reach [beyond the paper]. Random exploration still starts beside a target. False: every trial starts afresh,
    each learner within sensing range of a target [choice]."""
    guide: Guide | None = None
    """Part of the exploration takes a hand-made law's move instead of a uniform one (:class:`sim.guide.Guide`)
    [beyond the paper]; None: uniform exploration [paper]."""


TRIAL_RULES: dict[str, TrialRules] = {
    r.name: r
    for r in (
        TrialRules("paper"),
        TrialRules("search-on", lost_ends_trial=False, timeout_terminal=False),
        TrialRules("lost-searches", lost_ends_trial=False),
        TrialRules("continuing", lost_ends_trial=False, timeout_terminal=False, continuing=True),
        TrialRules("continuing-cut", lost_ends_trial=False, continuing=True),
        TrialRules("guided-search", lost_ends_trial=False, guide=Guide("force-6d-shared", explore=0.5, epsilon=0.5)),
    )
}
"""Every set of learning-trial rules by name: ``paper`` [paper §4]; ``search-on``, a lost learner searches and goes
on learning and the time-out bootstraps; ``lost-searches``, the same with the paper's terminal time-out;
``continuing``, ``search-on`` in arenas that carry over from trial to trial for a test trial's length, and
``continuing-cut`` the same with the terminal time-out; ``guided-search``, ``lost-searches`` with half of the
exploration's moves taken from the force law on the learned state's information, ``force-6d-shared`` [beyond the
paper]."""
PAPER_RULES = TRIAL_RULES["paper"]


T = TypeVar("T")


def _lookup(part: str, name: str, registry: dict[str, T], known: tuple[str, ...] | None = None) -> T:
    try:
        return registry[name]
    except KeyError:
        raise ValueError(f"unknown {part} {name!r}; known: {', '.join(known or registry)}") from None


@dataclass(frozen=True, slots=True, eq=False)
class Formulation:
    """What a learning problem is made of besides the algorithm (module docstring), as resolved objects.

    Two formulations are equal when their parts' names, ``act_every`` and trial rules are.
    """

    featurizer: Featurizer
    reward: Reward
    actions: ActionSet
    act_every: int | None = None
    """Steps between a robot's decisions in test trials; None: ``action_steps``, as it learned [paper]. Learning
    always holds an action ``action_steps`` steps."""
    trial_rules: TrialRules = field(default=PAPER_RULES)
    """The learning-trial rules."""

    def __post_init__(self) -> None:
        if self.act_every is not None and self.act_every < 1:
            raise ValueError(f"act_every must be at least 1, got {self.act_every}")

    @classmethod
    def of(
        cls,
        featurizer: str,
        reward: str,
        actions: str,
        *,
        act_every: int | None = None,
        trial_rules: str = "paper",
    ) -> Formulation:
        """The formulation of these part names; ``reward`` ``paper`` is the featurizer's own. ValueError names an
        unknown name and the known ones."""
        state = _lookup("featurizer", featurizer, FEATURIZER_REGISTRY)
        reward = state.paper_reward if reward == "paper" else reward
        return cls(
            state,
            _lookup("reward", reward, REWARDS, REWARD_NAMES),
            _lookup("action set", actions, ACTION_SETS),
            act_every,
            _lookup("trial rules", trial_rules, TRIAL_RULES),
        )

    def replace(
        self,
        *,
        featurizer: str | None = None,
        reward: str | None = None,
        actions: str | None = None,
        act_every: int | None = None,
        trial_rules: str | None = None,
    ) -> Formulation:
        """This formulation with the parts named here over its own (None keeps a part; ``act_every`` None keeps
        this one's)."""
        return Formulation.of(
            featurizer or self.featurizer.name,
            reward or self.reward.name,
            actions or self.actions.name,
            act_every=self.act_every if act_every is None else act_every,
            trial_rules=trial_rules or self.trial_rules.name,
        )

    @property
    def text(self) -> str:
        """Every part by name on one line, ``featurizer/reward/actions/act_every/rules`` (``act_every`` ``none`` for
        None), e.g. ``frame9d/difference-decision/relative/1/paper``: what a job file records (:meth:`parse`)."""
        every = "none" if self.act_every is None else str(self.act_every)
        return "/".join((*self.names, every, self.trial_rules.name))

    @classmethod
    def parse(cls, text: str) -> Formulation:
        """The formulation :attr:`text` names; ValueError names what is wrong."""
        parts = text.split("/")
        if len(parts) != 5:
            raise ValueError(f"expected featurizer/reward/actions/act_every/rules, got {text!r}")
        featurizer, reward, actions, every, trial_rules = parts
        try:
            act_every = None if every.lower() == "none" else int(every)
        except ValueError:
            raise ValueError(f"act_every must be an integer or none, got {every!r}") from None
        return cls.of(featurizer, reward, actions, act_every=act_every, trial_rules=trial_rules)

    @property
    def names(self) -> tuple[str, str, str]:
        """(featurizer, reward, action set) names: what the wire and the policy file carry."""
        return self.featurizer.name, self.reward.name, self.actions.name

    @property
    def dim(self) -> int:
        """d, the state's dimension."""
        return self.featurizer.dim

    @property
    def base_law(self) -> str:
        """The hand-made controller a policy of this formulation is measured against first, by its CLI name: for a
        law action set the law its move ``law`` follows, on the state's own information (``force-recall`` for a
        remembering state, ``force-6d-shared`` otherwise), so that what learning added over it is the difference; for
        other sets the tuned A-CMOMMT."""
        if self.actions.law is None:
            return "a-cmommt"
        return "force-recall" if self.featurizer.recalls else "force-6d-shared"

    def describe(self) -> str:
        every = {None: "every action", 1: "every step"}.get(self.act_every, f"every {self.act_every} steps")
        rules = "" if self.trial_rules == PAPER_RULES else f", {self.trial_rules.name} trial rules"
        return (
            f"{self.featurizer.name} state, {self.reward.name} reward, {self.actions.name} moves, deciding {every} "
            f"in tests{rules}"
        )

    def _key(self) -> tuple[object, ...]:
        return (*self.names, self.act_every, self.trial_rules)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Formulation) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __repr__(self) -> str:
        rules = "" if self.trial_rules == PAPER_RULES else f", trial_rules={self.trial_rules.name!r}"
        return f"Formulation.of({', '.join(map(repr, self.names))}, act_every={self.act_every!r}{rules})"


REWARD_NAMES: tuple[str, ...] = ("paper", *REWARDS)
"""What a configuration may name as its reward: ``paper`` is the featurizer's own (``observed`` for ``local2d``,
``eq2`` for the collaborative states)."""

FORMULATIONS: dict[str, Formulation] = {
    "paper": Formulation.of("collab6d", "eq2", "compass"),
    "shared-difference": Formulation.of("shared8d", "difference", "compass", act_every=1),
    "frame-difference": Formulation.of("frame9d", "difference-decision", "relative", act_every=1),
    "frame-cooperative": Formulation.of(
        "frame9d", "difference-redundancy", "relative", act_every=1, trial_rules="lost-searches"
    ),
    "frame-guided": Formulation.of(
        "frame9d", "difference-redundancy", "relative", act_every=1, trial_rules="guided-search"
    ),
    "frame-recall": Formulation.of(
        "frame11d-recall", "difference-redundancy", "relative", act_every=1, trial_rules="guided-search"
    ),
    "frame-law": Formulation.of("frame9d", "difference-redundancy", "law", act_every=1, trial_rules="guided-search"),
    "frame-recall-law": Formulation.of(
        "frame11d-recall", "difference-redundancy", "law", act_every=1, trial_rules="guided-search"
    ),
    "frame-recall-search": Formulation.of(
        "frame11d-recall", "difference-redundancy", "law-search", act_every=1, trial_rules="guided-search"
    ),
    "frame-recall-track": Formulation.of(
        "frame11d-recall", "difference-redundancy", "law-track", act_every=1, trial_rules="guided-search"
    ),
    "frame-recall-split": Formulation.of(
        "frame11d-recall", "coverage-split", "law-track", act_every=1, trial_rules="guided-search"
    ),
}
"""Every formulation by name; each one's measurements are the entry of docs/notebook.md named after it: ``paper``
is the paper's collaborative formulation [paper §4, Eq. 2]; ``shared-difference`` the best with the world-frame
state and compass moves that the ablations found ("2026-12-02: learning beyond the paper: the shared state and the
difference reward"); ``frame-difference`` the state and the moves in the frame of the nearest target, the difference
reward paid per decision ("2026-12-02: the frame-difference formulation"); ``frame-cooperative`` the same with a
redundant step charged (``difference-redundancy``) and learning trials in which a learner that loses every target
searches and goes on learning (``lost-searches``) [beyond the paper; "2026-12-03: lost learners search, and a charge
for redundant robots"]; ``frame-guided`` the same with exploration guided by the force law on the state's
information (``guided-search``) [beyond the paper; "2026-12-04: exploration guided by the force law"];
``frame-recall`` ``frame-guided`` on a state that remembers the targets a robot lost (:mod:`sim.recall`) [beyond
the paper; "2026-12-04: a memory of every target the robot lost"]; ``frame-law`` and ``frame-recall-law`` the same
two with the moves named from the pull of the force law on the state's information (``law`` moves), so that
following the law is one of the learned choices [beyond the paper; "2026-12-04: the law's move as one of the learned
choices"]; ``frame-recall-search`` ``frame-recall-law`` with ``law-search`` moves: where the law pulls nowhere they
are named from the robot's search heading, so that leaving a crowd to search along it is the move ``law`` [beyond
the paper; "2026-12-04: leaving a crowd along the search heading"]; ``frame-recall-track`` the same with
``law-track`` moves, whose search heading follows the law's pull, so that ``law`` is the hand-made law's own move
everywhere, its search included [beyond the paper; "2026-12-05: the law's own search as a learned move"];
``frame-recall-split`` the same paid ``coverage-split``, whose team total is metric A's summand at every step [beyond
the paper; "2026-12-07: one saved policy, the reward that misranks, the split reward"]."""
DEFAULT_FORMULATION = "frame-recall-track"
"""The formulation of every process (``up``, ``learner``, ``actor``, compose's) unless another is named."""


def default_formulation() -> Formulation:
    """The run's default formulation, :data:`DEFAULT_FORMULATION`."""
    return FORMULATIONS[DEFAULT_FORMULATION]


def resolve_formulation(
    name: str,
    *,
    featurizer: str | None = None,
    reward: str | None = None,
    actions: str | None = None,
    act_every: int | None = None,
    trial_rules: str | None = None,
) -> Formulation:
    """The formulation ``name`` with the parts given explicitly over its own (:meth:`Formulation.replace`); a
    ``reward`` of ``paper`` becomes the state's own. ValueError names an unknown name."""
    base = _lookup("formulation", name, FORMULATIONS)
    return base.replace(
        featurizer=featurizer, reward=reward, actions=actions, act_every=act_every, trial_rules=trial_rules
    )


def choices_help(part: str) -> str:
    """The names a configuration may give ``part`` (``formulation``, ``featurizer``, ``reward``, ``actions`` or
    ``trial_rules``), comma-separated, for a ``--help`` text: read from its registry, so a new entry is offered
    without another edit."""
    names = {
        "formulation": tuple(FORMULATIONS),
        "featurizer": tuple(FEATURIZER_REGISTRY),
        "reward": REWARD_NAMES,
        "actions": tuple(ACTION_SETS),
        "trial_rules": tuple(TRIAL_RULES),
    }[part]
    return ", ".join(names)
