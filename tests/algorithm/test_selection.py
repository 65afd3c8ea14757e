"""Keeping a run's best policy, and the law margin it is read with, by validation trials (``algorithm.selection``)."""

from __future__ import annotations

import dataclasses
import math
import threading
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from algorithm import selection
from algorithm.discretization import Discretization
from algorithm.policy import Policy, PolicyController
from algorithm.selection import (
    LAW_MARGINS,
    VALIDATION_SEED,
    BestPolicy,
    ScoringStopped,
    choose_margin,
    rank,
    reference_spread,
    within,
)
from sim import N_ACTIONS, evaluate, scenario
from sim.controllers import HAND_MADE
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS

CFG = scenario("cmommt-v1")
FORMULATION = FORMULATIONS[DEFAULT_FORMULATION]


def constant(action: int, version: int) -> Policy:
    """A policy that always takes ``action``: one cell per action, the highest value on ``action``'s."""
    disc = Discretization.from_per_action([np.zeros((1, FORMULATION.dim), np.float32)] * N_ACTIONS)
    tables = np.zeros((1, N_ACTIONS), np.float32)
    tables[0, action] = 1.0
    return Policy(
        formulation=FORMULATION,
        discretization=disc,
        tables=tables,
        robot_table=np.zeros(CFG.n_robots, np.int64),
        action_steps=1,
        version=version,
    )


def validation(policy: Policy, trials: int) -> float:
    return evaluate(CFG, PolicyController(policy), trials, 100, seed=VALIDATION_SEED).coverage_mean


def test_the_best_on_the_validation_trials_is_kept_whenever_it_came() -> None:
    policies = [constant(a, version=a + 1) for a in range(N_ACTIONS)]
    scores = [validation(p, 3) for p in policies]
    assert len(set(scores)) > 2  # the actions differ, so the choice is not a tie
    best = int(np.argmax(scores))
    # The best in the middle, a worse one last: the last policy is not the one kept.
    worse = int(np.argmin(scores))
    order = [i for i in range(N_ACTIONS) if i not in (best, worse)]
    order = [*order[:3], best, *order[3:], worse]
    keeper = BestPolicy(CFG, trials=3, steps=100)
    offered = [keeper.offer(policies[i], at=float(k)) for k, i in enumerate(order)]
    assert offered == [scores[i] for i in order]  # the validation trials are the seed's, the same every time
    assert keeper.best is not None and keeper.best.policy is policies[best]
    assert keeper.best.coverage == max(scores) and keeper.best.at == float(order.index(best))
    assert [c for _, c in keeper.scores] == [round(scores[i], 3) for i in order]
    # A tie keeps the earlier policy.
    keeper.offer(constant(best, version=99), at=99.0)
    assert keeper.best.policy is policies[best]


def test_the_validation_trials_are_not_the_test_trials() -> None:
    policy = constant(0, version=1)
    test = evaluate(CFG, PolicyController(policy), 20, 100, seed=0).coverage_per_trial
    valid = evaluate(CFG, PolicyController(policy), 20, 100, seed=VALIDATION_SEED).coverage_per_trial
    assert not np.isin(valid, test).all()  # other arenas, not the reported ones reordered


def test_the_kept_policy_survives_a_restore_and_is_forgotten_without_its_file() -> None:
    keeper = BestPolicy(CFG, trials=2, steps=100)
    first, second = constant(1, version=1), constant(5, version=2)
    keeper.offer(first, at=1.0)
    keeper.offer(second, at=2.0)
    assert keeper.best is not None
    meta = keeper.to_meta()
    again = BestPolicy(CFG, trials=2, steps=100)
    again.restore(meta, keeper.best.policy)
    assert again.scores == keeper.scores and again.best is not None
    assert (again.best.coverage, again.best.at) == (keeper.best.coverage, keeper.best.at)
    lost = BestPolicy(CFG, trials=2, steps=100)
    lost.restore(meta, None)
    assert lost.best is None and lost.scores == keeper.scores
    lost.offer(first, at=3.0)  # the next offer is kept, whatever its score
    assert lost.best is not None and lost.best.policy is first


def law_or_back(gap: float) -> Policy:
    """A policy whose only departure is ``back``, valued ``gap`` above the move ``law`` everywhere."""
    policy = constant(0, version=1)
    tables = np.zeros_like(policy.tables)
    tables[0, FORMULATION.actions.moves.index("back")] = gap
    return dataclasses.replace(policy, tables=tables)


def test_a_law_margin_departs_from_law_only_where_another_move_beats_it_by_more() -> None:
    states = np.zeros((4, FORMULATION.dim), np.float32)
    robots = np.arange(4)
    back = FORMULATION.actions.moves.index("back")
    policy = law_or_back(0.2)
    for margin, expected in [(0.0, back), (0.1, back), (0.2, 0), (0.3, 0)]:
        chosen = dataclasses.replace(policy, law_margin=margin).greedy(states, robots)
        assert chosen.tolist() == [expected] * 4, margin


def test_a_law_margin_is_refused_without_a_law_action_set_or_when_not_a_finite_number_above_0() -> None:
    policy = constant(0, version=1)
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="law_margin"):
            dataclasses.replace(policy, law_margin=bad)
    compass = Policy(
        formulation=FORMULATIONS["paper"],
        discretization=Discretization.from_per_action([np.zeros((1, FORMULATIONS["paper"].dim), np.float32)] * 8),
        tables=np.zeros((1, 8), np.float32),
        robot_table=np.zeros(CFG.n_robots, np.int64),
    )
    with pytest.raises(ValueError, match="law action set"):
        dataclasses.replace(compass, law_margin=0.1)


def test_the_margin_chosen_is_the_smallest_that_scores_best_on_the_validation_trials() -> None:
    # Running from every target (back) scores far under the law; margins at or above the gap of 0.25 read the law.
    choice = choose_margin(CFG, law_or_back(0.25), trials=3, steps=100)
    assert choice.margin == 0.3 and (choice.trials, choice.seed) == (3, VALIDATION_SEED)
    assert list(choice.scores) == list(LAW_MARGINS)
    assert choice.scores[0.3] == choice.scores[0.5] == validation(constant(0, version=1), 3)
    assert choice.scores[0.0] == choice.scores[0.2] < choice.scores[0.3] - 10


def test_a_margin_choice_gives_up_before_its_next_margin_once_its_stop_is_set(monkeypatch: pytest.MonkeyPatch) -> None:
    scored: list[float | None] = []
    real = selection.evaluate

    def counted(cfg: Any, controller: Any, *args: Any, **kwargs: Any) -> Any:
        scored.append(controller.policy.law_margin)
        return real(cfg, controller, *args, **kwargs)

    monkeypatch.setattr(selection, "evaluate", counted)
    stop = threading.Event()
    checks = [0]

    def set_after_two() -> bool:  # set while the third margin would be scored
        checks[0] += 1
        return checks[0] > 2

    stop.is_set = set_after_two  # type: ignore[method-assign]
    with pytest.raises(ScoringStopped):
        choose_margin(CFG, law_or_back(0.25), trials=3, steps=100, stop=stop)
    assert scored == list(LAW_MARGINS[:2])
    scored.clear()
    assert choose_margin(CFG, law_or_back(0.25), trials=3, steps=100, stop=threading.Event()).margin == 0.3
    assert scored == list(LAW_MARGINS)


# Each margin's (coverage %, robots per covered target) on the validation trials: the best coverage (0.1) is the
# thickest team; 0.2 and 0.3 tie within a cap of 1.06.
SCORED = {0.0: (78.0, 1.20), 0.1: (79.0, 1.10), 0.2: (78.5, 1.06), 0.3: (78.5, 1.05), 0.5: (77.0, 1.04)}
SCORED |= {1.0: (76.0, 1.03), 2.0: (75.0, 1.02)}


@pytest.mark.parametrize(("cap", "margin"), [(None, 0.1), (1.06, 0.2), (1.05, 0.3), (1.025, 2.0), (1.0, 0.1)])
def test_a_capped_margin_choice_takes_the_best_margin_whose_spread_is_within_the_cap_where_one_is(
    monkeypatch: pytest.MonkeyPatch, cap: float | None, margin: float
) -> None:
    def scored(cfg: Any, controller: Any, *args: Any, **kwargs: Any) -> Any:
        coverage, spread = SCORED[controller.policy.law_margin]
        return SimpleNamespace(coverage_mean=coverage, robots_per_covered_target=spread)

    monkeypatch.setattr(selection, "evaluate", scored)
    choice = choose_margin(CFG, law_or_back(0.25), trials=3, steps=100, cap=cap)
    # Under a cap no margin is within (1.0), the choice is coverage's alone.
    assert choice.margin == margin
    assert choice.scores == {m: c for m, (c, _) in SCORED.items()}
    assert choice.spreads == {m: r for m, (_, r) in SCORED.items()}


def test_candidates_rank_within_the_cap_first_then_by_coverage_and_an_unknown_spread_is_not_within() -> None:
    assert rank(79.0, 1.10, None) > rank(78.0, 1.05, None)  # no cap: coverage alone
    assert rank(78.0, 1.05, 1.06) > rank(79.0, 1.10, 1.06) and rank(78.0, 1.06, 1.06) > rank(77.0, 1.06, 1.06)
    assert rank(79.0, 1.10, 1.06) > rank(78.0, 1.07, 1.06)  # neither within: coverage
    assert rank(78.0, 1.05, 1.06) > rank(79.0, None, 1.06) and rank(78.0, 1.05, 1.06) > rank(79.0, math.nan, 1.06)
    assert within(None, None) and not within(None, 1.06) and within(1.06, 1.06)


def test_a_reference_s_spread_is_its_robots_per_covered_target_on_the_validation_trials() -> None:
    law = evaluate(CFG, HAND_MADE["a-cmommt"], 3, 100, seed=VALIDATION_SEED).cooperation
    assert law is not None and law.covered.sum() > 0
    spread = reference_spread(CFG, "a-cmommt", trials=3, steps=100)
    assert spread == law.sightings.sum() / law.covered.sum() and spread >= 1.0  # each covered target: 1 robot or more
    # The public law piles onto targets its teammates watch: its spread is the thicker.
    assert reference_spread(CFG, "a-cmommt-public", trials=3, steps=100) > spread


def test_the_decisions_off_law_are_counted_for_a_law_set_only() -> None:
    from algorithm.policy import evaluate_off_law

    runs_away = law_or_back(0.25)
    plain, off = evaluate_off_law(CFG, runs_away, 2, 50, seed=0)
    assert off == 100.0 and plain.coverage_mean == coverage_on_two_trials(runs_away)
    _, off = evaluate_off_law(CFG, dataclasses.replace(runs_away, law_margin=0.3), 2, 50, seed=0)
    assert off == 0.0
    # Half the robots' rows favour back: half the decisions leave law.
    tables = np.concatenate([runs_away.tables, np.zeros_like(runs_away.tables)])
    split = dataclasses.replace(runs_away, tables=tables, robot_table=np.arange(CFG.n_robots) % 2)
    _, off = evaluate_off_law(CFG, split, 2, 50, seed=0)
    assert off == 50.0


def coverage_on_two_trials(policy: Policy) -> float:
    return evaluate(CFG, PolicyController(policy), 2, 50, seed=0).coverage_mean
