"""Guided exploration (trial rules ``guided-search``): a hand-made law's move as an action, and how much of the
exploration takes it."""

from __future__ import annotations

import numpy as np
import pytest

from actors.config import ActorConfig
from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.trials import ExperienceSlice, SliceConfig
from sim import FORMULATIONS, N_ACTIONS, Formulation, scenario
from sim.actions import ACTION_SETS
from sim.config import ScenarioConfig
from sim.controllers import HAND_MADE
from sim.formulation import TRIAL_RULES, TrialRules
from sim.guide import GUIDES, Guide
from sim.trial import TrialState, random_actions, reset_trial, step_trial
from tests.fakes import situation

COOPERATIVE = FORMULATIONS["frame-cooperative"]
GUIDED = FORMULATIONS["frame-guided"]
AWAY = 4  # the relative move directly away from the nearest target


def guided(explore: float, epsilon: float) -> Formulation:
    """``frame-cooperative`` with a guide of these shares in its trial rules."""
    rules = TrialRules("test-guided", lost_ends_trial=False, guide=Guide(explore=explore, epsilon=epsilon))
    return Formulation(COOPERATIVE.featurizer, COOPERATIVE.reward, COOPERATIVE.actions, COOPERATIVE.act_every, rules)


@pytest.mark.parametrize("name", ["relative", "compass"])
def test_closest_is_the_action_whose_world_move_points_most_along_the_velocity(name: str) -> None:
    moves = ACTION_SETS[name]
    rng = np.random.default_rng(0)
    angle = rng.uniform(0, 2 * np.pi, 500)
    x = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    mirror = np.where(rng.random(500) < 0.5, 1.0, -1.0)[:, None]
    frame = np.stack([x, mirror * np.stack([-x[:, 1], x[:, 0]], axis=-1)], axis=1)
    velocity = rng.normal(size=(500, 2)) * rng.uniform(0.1, 5.0, (500, 1))
    got = moves.closest(velocity, frame)
    cfg = scenario()
    each = np.stack([moves.velocity(cfg, np.full(500, a), frame) for a in range(N_ACTIONS)], axis=1)
    cosine = (each * velocity[:, None]).sum(-1) / np.linalg.norm(velocity, axis=-1, keepdims=True)
    np.testing.assert_array_equal(got, cosine.argmax(axis=1))
    # A move given exactly as one of the set's moves comes back as that action.
    picked = rng.integers(0, N_ACTIONS, 500)
    np.testing.assert_array_equal(moves.closest(moves.velocity(cfg, picked, frame), frame), picked)


def test_the_guides_move_is_the_action_nearest_the_laws_velocity() -> None:
    cfg = scenario()
    state = reset_trial(cfg, 200, np.ones(cfg.n_robots, bool), COOPERATIVE, np.random.default_rng(3))
    guide = Guide("force-6d-shared")
    velocity, _ = HAND_MADE["force-6d-shared"].act(cfg, state.world, state.obs, state.heading, np.random.default_rng())
    chosen = guide.actions(cfg, state)
    frame = COOPERATIVE.actions.frame(state.view)
    move = COOPERATIVE.actions.velocity(cfg, chosen, frame)
    unit = velocity / np.linalg.norm(velocity, axis=-1, keepdims=True)
    # Eight moves 45° apart: the chosen one is within 22.5° of the law's direction.
    assert ((move * unit).sum(-1) / cfg.robot_speed >= np.cos(np.pi / 8) - 1e-9).all()
    assert len(np.unique(chosen)) > 3


def _constant_guide(monkeypatch: pytest.MonkeyPatch, action: int) -> None:
    """Every guide's move becomes ``action``, so a tuple shows whether exploration took the guide's move."""

    def constant(self: Guide, cfg: ScenarioConfig, state: TrialState, rows: np.ndarray | None = None) -> np.ndarray:
        return np.full(state.shape if rows is None else rows.shape, action)

    monkeypatch.setattr(Guide, "actions", constant)


@pytest.mark.parametrize("name", ["frame-guided", "frame-recall"])
def test_the_guides_moves_of_some_robots_are_their_moves_among_all(name: str) -> None:
    # Exploration asks the law for the few robots that take its move; each must get the move it gets among all.
    cfg = scenario()
    formulation = FORMULATIONS[name]
    rng = np.random.default_rng(3)
    state = reset_trial(cfg, n_arenas=50, learners=True, formulation=formulation, rng=rng)
    decide = np.ones(state.shape, bool)
    for _ in range(40):  # some robots lose their targets, and remembering ones then read a memory
        state, out = step_trial(cfg, state, random_actions(state, rng), decide, rng)
        decide = out.decide
    guide = formulation.trial_rules.guide
    assert guide is not None
    every = guide.actions(cfg, state).reshape(-1)
    rows = np.random.default_rng(0).choice(every.size, 37, replace=False)
    np.testing.assert_array_equal(guide.actions(cfg, state, rows), every[rows])
    assert len(set(every[rows].tolist())) > 1


@pytest.mark.parametrize("share", [0.0, 0.5, 1.0])
def test_random_exploration_takes_the_guides_move_at_its_share_of_decisions(
    monkeypatch: pytest.MonkeyPatch, share: float
) -> None:
    _constant_guide(monkeypatch, 5)
    cfg = scenario()
    batch = ExperienceSlice(cfg, SliceConfig(guided(share, 0.0), n_arenas=100), seed=1).run_trial()
    taken = (batch.action == 5).mean()
    # Uniform decisions pick action 5 an eighth of the time too.
    assert taken == pytest.approx(share + (1 - share) / N_ACTIONS, abs=0.02)


def _agent(cfg_robots: int, epsilon: float) -> TabularAgent:
    disc = Discretization.from_per_action([np.zeros((1, COOPERATIVE.dim))] * N_ACTIONS)
    tables = np.zeros((1, disc.size), np.float32)
    tables[0, 2] = 1.0  # the greedy move is action 2 everywhere
    policy = Policy(COOPERATIVE, disc, tables, np.zeros(cfg_robots, np.int64))
    return TabularAgent(policy, Phase2Config(epsilon=epsilon, alpha=1e-9))


@pytest.mark.parametrize(("epsilon", "share"), [(1.0, 1.0), (1.0, 0.5), (0.2, 1.0)])
def test_epsilon_explorations_take_the_guides_move_at_its_share(
    monkeypatch: pytest.MonkeyPatch, epsilon: float, share: float
) -> None:
    _constant_guide(monkeypatch, 5)
    cfg = scenario()
    sl = ExperienceSlice(cfg, SliceConfig(guided(0.0, share), n_arenas=100), seed=2)
    batch = sl.run_trial(_agent(cfg.n_robots, epsilon), update=True)
    explored = epsilon * (share + (1 - share) / N_ACTIONS)
    assert (batch.action == 5).mean() == pytest.approx(explored, abs=0.02)
    assert (batch.action == 2).mean() == pytest.approx(1 - epsilon + epsilon * (1 - share) / N_ACTIONS, abs=0.02)


def test_guided_exploration_earns_more_than_uniform_exploration() -> None:
    cfg = scenario()

    def mean_reward(formulation: Formulation) -> float:
        sl = ExperienceSlice(cfg, SliceConfig(formulation, n_arenas=100), seed=4)
        return float(np.mean([sl.run_trial().reward.mean() for _ in range(2)]))

    assert mean_reward(guided(1.0, 0.5)) > mean_reward(COOPERATIVE) + 0.15


def test_without_a_guide_the_slice_draws_the_stream_it_always_drew() -> None:
    cfg = scenario()
    plain = ExperienceSlice(cfg, SliceConfig(COOPERATIVE, n_arenas=32), seed=7).run_trial()
    unguided = ExperienceSlice(cfg, SliceConfig(guided(0.0, 0.0), n_arenas=32), seed=7).run_trial()
    np.testing.assert_array_equal(plain.action, unguided.action)
    np.testing.assert_array_equal(plain.state, unguided.state)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"law": "a-cmommt"}, "guide: unknown law 'a-cmommt' (known: force-6d, force-6d-shared)"),
        ({"explore": -0.1}, "guide explore share must lie in [0, 1], got -0.1"),
        ({"law": "force-6d", "epsilon": 2.0}, "guide epsilon share must lie in [0, 1], got 2.0"),
    ],
)
def test_a_bad_guide_is_refused(settings: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError) as error:
        Guide(**settings)  # type: ignore[arg-type]
    assert str(error.value) == message
    assert set(GUIDES) == {"force-6d", "force-6d-shared"}


def test_the_default_formulation_explores_guided_and_the_papers_does_not() -> None:
    default = ActorConfig().resolved
    assert default == FORMULATIONS["frame-recall-track"] and default.trial_rules == TRIAL_RULES["guided-search"]
    assert GUIDED.trial_rules == TRIAL_RULES["guided-search"]
    assert GUIDED.trial_rules.guide == Guide("force-6d-shared", explore=0.5, epsilon=0.5)
    assert FORMULATIONS["paper"].trial_rules.guide is None and COOPERATIVE.trial_rules.guide is None
    # Everything else is frame-cooperative's: the guide is the one difference.
    assert GUIDED.names == COOPERATIVE.names and GUIDED.act_every == COOPERATIVE.act_every
    assert GUIDED.trial_rules.lost_ends_trial == COOPERATIVE.trial_rules.lost_ends_trial


def test_a_guided_robot_that_remembers_its_lost_target_is_pulled_back_to_it() -> None:
    cfg = scenario(n_robots=1, n_targets=1, action_steps=1, learning_steps=30, recall_steps=10, target_turn_prob=0.0)
    # The target runs east at 20 per step from the robot 145 west of it, which moves "away" (west) for 6 steps: it
    # loses the target on the first and ends 190 from where it last saw it, beyond the public law's do4 of 180.
    start = ([(-145.0, 0.0)], [(0.0, 0.0)], [True])
    common = {"target_vel": [(20.0, 0.0)], "heading": [(0.0, 1.0)]}
    rng = np.random.default_rng(0)
    moves = {}
    for name in ("frame-guided", "frame-recall"):
        formulation = FORMULATIONS[name]
        state = situation(cfg, *start, formulation=formulation, **common)
        for _ in range(6):
            state, _ = step_trial(cfg, state, np.full((1, 1), AWAY), np.ones((1, 1), bool), rng)
        assert state.obs.n_seen[0, 0] == 0
        chosen = formulation.trial_rules.guide.actions(cfg, state)
        moves[name] = formulation.actions.velocity(cfg, chosen, formulation.actions.frame(state.view))[0, 0]
    # Forgetting, the law pulls nowhere and the guide keeps the search heading (north); remembering, the law reads
    # the remembered target (east of the robot, where it last saw it) and the guide moves towards it.
    np.testing.assert_allclose(moves["frame-guided"] / cfg.robot_speed, (0.0, 1.0), atol=1e-9)
    np.testing.assert_allclose(moves["frame-recall"] / cfg.robot_speed, (1.0, 0.0), atol=1e-9)
