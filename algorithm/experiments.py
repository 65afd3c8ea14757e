"""One learning process of each method of the paper, end to end on the vectorized simulator.

A process explores with random actions (phase 0), builds a discretization (ENNC-QL phase 1, or the LBG codebook of
VQQL), learns Q tables on-line with ε-greedy tabular Q-learning (phase 2), and is then tested on seeded 1000-step
trials with 10 robots. Usage::

    spec = METHODS["ennc-ql-collab-option2"]
    outcome = train(spec, Budget.quick(), seed=0)              # the method's formulation, or another one:
    outcome = train(spec, Budget.quick(), seed=0, formulation=spec.formulation.replace(reward="difference"))
    outcome.policy, outcome.coverage_mean, outcome.states
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.fqi import FQIConfig, NetworkController, QNetwork, collect, fit_q
from algorithm.phase1 import CMOMMT_PHASE1, Phase1Config, phase1
from algorithm.policy import ActionMode, LostBehaviour, Policy, PolicyController
from algorithm.selection import SaveRule
from algorithm.transitions import Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from algorithm.vqql import lbg
from sim import N_ACTIONS, ScenarioConfig, evaluate, scenario
from sim.formulation import Formulation

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class MethodSpec:
    """How one method of Figure 5 learns."""

    name: str
    algorithm: str
    """``enncql``, ``vqql``, or ``fqi`` (the neural fitted-Q reference of :mod:`algorithm.fqi`, not the paper's)."""
    featurizer: str
    """Its state [paper: ``local2d`` or ``collab6d``]."""
    learning_robots: int
    """Robots present in learning trials: 1 for the local experiments, 10 for the collaborative ones [paper]."""
    per_robot_tables: bool
    """Option 2: every robot learns its own table [paper]; otherwise robot 0 learns and all use its table."""
    codebook: int = 0
    """VQQL codebook size."""
    reward: str = "paper"
    """Reward function of the learners; ``paper``: the featurizer's own."""
    actions: str = "compass"
    """Action set [paper: the compass moves]."""
    shared_table: bool = False
    """Every robot learns (as in option 2) into ONE table that every robot uses [beyond the paper]."""
    phase2_reward: str | None = None
    """Reward of phase 2's learners when it differs from the one phase 1's discretization is fitted on; None:
    ``reward`` [beyond the paper]."""

    @property
    def formulation(self) -> Formulation:
        """The method's own formulation, resolved from its part names (ValueError names an unknown one)."""
        return Formulation.of(self.featurizer, self.reward, self.actions)


METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in [
        MethodSpec("vqql-local-16", "vqql", "local2d", 1, False, codebook=16),
        MethodSpec("vqql-collab-64", "vqql", "collab6d", 10, False, codebook=64),
        MethodSpec("vqql-collab-256", "vqql", "collab6d", 10, False, codebook=256),
        MethodSpec("vqql-collab-1024", "vqql", "collab6d", 10, False, codebook=1024),
        MethodSpec("vqql-collab-2048", "vqql", "collab6d", 10, False, codebook=2048),
        MethodSpec("ennc-ql-local", "enncql", "local2d", 1, False),
        MethodSpec("ennc-ql-collab-option1", "enncql", "collab6d", 10, False),
        MethodSpec("ennc-ql-collab-option2", "enncql", "collab6d", 10, True),
        MethodSpec("fqi-mlp", "fqi", "collab6d", 10, False),
    ]
}


UNUSED_BUDGET: dict[str, tuple[str, ...]] = {
    "fqi": (
        "phase1",
        "phase2",
        "codebook_patterns",
        "refits",
        "refit_tuples",
        "refit_seed_prototypes",
        "law_margin_trials",
    ),
    "vqql": ("phase1", "refits", "refit_tuples", "refit_seed_prototypes", "fqi"),
    "enncql": ("codebook_patterns", "fqi"),
}
"""The fields of :class:`Budget` that a method's algorithm never reads (a sweep of one would change nothing)."""


@dataclass(frozen=True, slots=True)
class Budget:
    """How much experience and computation one learning process gets."""

    arenas: int = 500
    """Arenas simulated side by side in learning trials."""
    explore_trials: int = 6
    """Batches of random-exploration learning trials (phase 0), each in every arena."""
    phase2_trials: int = 60
    """Batches of ε-greedy learning trials (phase 2)."""
    phase1: Phase1Config = field(default_factory=lambda: CMOMMT_PHASE1)
    """ENNC-QL phase 1, as the learner fits it."""
    phase2: Phase2Config = field(default_factory=Phase2Config)
    codebook_patterns: int = 50_000
    """LBG runs on a uniform sample of this many explored states [choice]."""
    team_policy: bool = False
    """Test the policy with the robots' tables merged into one by their visits (:meth:`Policy.team`, the learner's
    default); False: each robot on its own row, as the paper's option 2 [paper]."""
    refits: int = 0
    """ENNC-QL: phase 2's batches are cut into ``refits`` + 1 equal parts; after each but the last, phase 1 runs
    again on the part's on-policy tuples (the newest ``refit_tuples``), warm-started from the current
    discretization, its targets bootstrapped from the learned tables, which then carry over [beyond the paper]."""
    refit_tuples: int = 600_000
    """Tuples of a refit (the newest of its part of phase 2)."""
    refit_seed_prototypes: int | None = None
    """``seed_prototypes`` of the refits' phase 1 (more data can hold more cells); None: ``phase1``'s."""
    fqi: FQIConfig = field(default_factory=FQIConfig)
    """The neural fitted-Q reference (method ``fqi-mlp``): it explores as phase 0 and learns on as many batches of
    learning trials as phase 2, in ``fqi.rounds`` rounds."""
    law_margin_trials: int = 300
    """A law action set's policy is saved by the learner's rule (:class:`algorithm.selection.SaveRule`): the last
    tables, read with the margin of :data:`algorithm.selection.LAW_MARGINS` that scores best on this many validation
    trials; 0: the argmax (margin 0 given) [beyond the paper]."""
    test_trials: int = 10
    """Test trials of each learning process [paper: 10]."""
    test_steps: int = 1000
    """Steps of a test trial [paper]."""
    test_seed: int = 0
    """Seed of the test trials: every method is tested on the same seeded trials, as the hand-made controllers are."""

    def __post_init__(self) -> None:
        if self.law_margin_trials < 0:
            raise ValueError(f"law_margin_trials must be >= 0 (0: the argmax), got {self.law_margin_trials}")

    @classmethod
    def quick(cls) -> Budget:
        return cls(
            arenas=500,
            explore_trials=2,
            phase2_trials=20,
            phase1=Phase1Config(max_iterations=1, max_patterns=20_000, n_cycles=150),
            codebook_patterns=20_000,
            law_margin_trials=30,
        )


@dataclass(frozen=True, slots=True)
class Outcome:
    method: str
    seed: int
    policy: Policy | None
    """The learned policy (None for the neural reference, which has no policy file)."""
    coverage_per_trial: np.ndarray
    states: float
    """Mean prototypes per action (ENNC-QL) or codebook size (VQQL)."""
    tuples: int
    seconds: float

    @property
    def coverage_mean(self) -> float:
        return float(self.coverage_per_trial.mean())


Progress = Callable[[str], None]


def _discretize(
    spec: MethodSpec, data: Transitions, budget: Budget, seed: int, cfg: ScenarioConfig, formulation: Formulation
) -> tuple[Discretization, ActionMode]:
    rng = np.random.default_rng(seed)
    if spec.algorithm == "vqql":
        n = min(budget.codebook_patterns, len(data))
        sample = data.state[rng.choice(len(data), n, replace=False)]
        return Discretization.shared(lbg(sample, spec.codebook, seed=seed, max_iter=30), N_ACTIONS), "until_change"
    lost = formulation.featurizer.sees_none(cfg, data.next_state)
    result = phase1(data, N_ACTIONS, budget.phase1, seed=seed, lost=lost, lost_reward=cfg.lost_reward)
    return result.discretization, "fixed"


def _train_fqi(
    spec: MethodSpec, budget: Budget, seed: int, base: ScenarioConfig, say: Progress, formulation: Formulation
) -> tuple[NetworkController, int]:
    """The neural reference learning process: exploration, fitted-Q iterations, on-policy rounds."""
    c = budget.fqi
    cfg = base.replace(n_robots=spec.learning_robots)
    rng = np.random.default_rng([seed, sum(spec.name.encode())])
    data = Transitions.concat(
        [collect(cfg, None, formulation, budget.arenas, 0.0, rng) for _ in range(budget.explore_trials)]
    )
    tuples = len(data)
    q = QNetwork.for_states(data.state, c, seed)
    fit_q(q, data, c, c.iterations, rng)
    per_round = max(1, round(budget.phase2_trials / c.rounds))
    for r in range(c.rounds):
        fresh = [collect(cfg, q, formulation, budget.arenas, c.epsilon, rng) for _ in range(per_round)]
        tuples += sum(len(t) for t in fresh)
        data = Transitions.concat([data, *fresh])
        data = data.take(slice(max(0, len(data) - c.buffer), None))
        fit_q(q, data, c, c.round_iterations, rng)
        say(f"round {r + 1}/{c.rounds}: {tuples} tuples")
    every = formulation.act_every or base.action_steps
    return NetworkController(q, formulation, act_every=every), tuples


def _refit(
    agent: TabularAgent, data: Transitions, budget: Budget, seed: int, cfg: ScenarioConfig
) -> tuple[TabularAgent, Discretization]:
    """Phase 1 again on on-policy ``data``, bootstrapped from the agent's tables (their mean over robots); a new
    agent over the new discretization with the tables carried over (each new cell from the nearest old one)."""
    old = agent.discretization
    config = budget.phase1
    if budget.refit_seed_prototypes is not None:
        config = dataclasses.replace(config, seed_prototypes=budget.refit_seed_prototypes)
    lost = agent.template.formulation.featurizer.sees_none(cfg, data.next_state)
    values = agent.tables.mean(axis=0)
    fit = phase1(
        data, N_ACTIONS, config, seed=seed, warm_start=old, values=values, lost=lost, lost_reward=cfg.lost_reward
    )
    disc = fit.discretization
    template = dataclasses.replace(agent.template, discretization=disc, tables=disc.carry_over(old, agent.tables))
    return TabularAgent(dataclasses.replace(template, visits=None), budget.phase2), disc


# Over 60 lines: one learning process from exploration to test, in the order of the paper's protocol; its steps
# share the slices and the budget.
def train(
    spec: MethodSpec,
    budget: Budget,
    seed: int,
    base: ScenarioConfig | None = None,
    progress: Progress | None = None,
    lost_behaviour: LostBehaviour = "wander",
    formulation: Formulation | None = None,
) -> Outcome:
    """One independent learning process of ``spec``, tested on the paper's protocol; ``lost_behaviour`` is what a
    robot that sees no target does in the test trials. ``formulation`` (None: the method's own) is what it learns
    on; its ``act_every`` is the steps between a robot's decisions in the test trials (None: ``action_steps``, as
    it learned)."""
    formulation = formulation or spec.formulation
    start = time.perf_counter()
    base = base or scenario()
    say = progress or (lambda message: log.info("%s[%d]: %s", spec.name, seed, message))
    if spec.algorithm == "fqi":
        network, tuples = _train_fqi(spec, budget, seed, base, say, formulation)
        result = evaluate(base, network, budget.test_trials, budget.test_steps, seed=budget.test_seed)
        say(f"test coverage {result.coverage_mean:.2f}%")
        return Outcome(spec.name, seed, None, result.coverage_per_trial, 0.0, tuples, time.perf_counter() - start)
    learn_cfg = base.replace(n_robots=spec.learning_robots)
    seeds = np.random.SeedSequence([seed, sum(spec.name.encode())]).spawn(2)
    explorer = ExperienceSlice(
        learn_cfg,
        SliceConfig(formulation, n_arenas=budget.arenas),
        seeds[0],
    )
    data = Transitions.concat([explorer.run_trial() for _ in range(budget.explore_trials)])
    say(f"explored {len(data)} tuples")
    disc, action_mode = _discretize(spec, data, budget, seed, learn_cfg, formulation)
    say(f"discretization: {disc.size} cells, {disc.sizes().mean():.1f} per action")
    rows = spec.learning_robots if spec.per_robot_tables and not spec.shared_table else 1
    phase2 = formulation.replace(reward=spec.phase2_reward)
    template = Policy(
        formulation=phase2,
        discretization=disc,
        tables=np.tile(disc.labels, (rows, 1)),
        robot_table=np.arange(spec.learning_robots) % rows,
        action_steps=base.action_steps,
        action_mode=action_mode,
        method=spec.name,
    )
    agent = TabularAgent(template, budget.phase2)
    learners = None if spec.per_robot_tables or spec.shared_table else (0,)
    learner_slice = ExperienceSlice(
        learn_cfg,
        SliceConfig(
            phase2,
            n_arenas=budget.arenas,
            learning_robots=learners,
            action_mode=action_mode,
        ),
        seeds[1],
    )
    tuples = len(data)
    refit_at = (
        set()
        if spec.algorithm == "vqql"
        else {round(k * budget.phase2_trials / (budget.refits + 1)) for k in range(1, budget.refits + 1)}
    )
    recent: list[Transitions] = []

    def acting() -> Policy:
        """The policy as tested: every test robot on its row, deciding as the formulation says."""
        policy = dataclasses.replace(
            agent.policy(robot_table=np.arange(base.n_robots) % rows, meta={"seed": seed, "tuples": tuples}),
            lost_behaviour=lost_behaviour,
            action_steps=formulation.act_every or base.action_steps,
        )
        return policy.team() if budget.team_policy else policy

    for trial in range(budget.phase2_trials):
        batch = learner_slice.run_trial(agent, update=True)
        tuples += len(batch)
        recent = [*recent, batch][-max(1, budget.refit_tuples // max(len(batch), 1)) :]
        if (trial + 1) % max(1, budget.phase2_trials // 4) == 0:
            say(f"phase 2: {trial + 1}/{budget.phase2_trials} trial batches, {tuples} tuples")
        if trial + 1 in refit_at:
            agent, disc = _refit(agent, Transitions.concat(recent), budget, seed + trial, learn_cfg)
            say(f"refit: {disc.sizes().mean():.1f} prototypes per action")
    trials = budget.law_margin_trials
    rule = SaveRule(base, law_margin=None if trials else 0.0, trials=max(trials, 1), steps=budget.test_steps)
    policy, saved = rule.decide(acting(), at=budget.phase2_trials)
    say(f"saved {saved.reason}" + ("" if saved.margin is None else f" (law margin {saved.margin:g})"))
    result = evaluate(base, PolicyController(policy), budget.test_trials, budget.test_steps, seed=budget.test_seed)
    say(f"test coverage {result.coverage_mean:.2f}%")
    states = float(spec.codebook) if spec.algorithm == "vqql" else float(disc.sizes().mean())
    return Outcome(
        method=spec.name,
        seed=seed,
        policy=policy,
        coverage_per_trial=result.coverage_per_trial,
        states=states,
        tuples=tuples,
        seconds=time.perf_counter() - start,
    )
