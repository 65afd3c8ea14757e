"""The one rule a run saves its policy by, and the law margin it is read with on validation trials
(``algorithm.selection``)."""

from __future__ import annotations

import dataclasses
import threading
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from algorithm import selection
from algorithm.discretization import Discretization
from algorithm.policy import Policy, PolicyController
from algorithm.selection import (
    FALLBACK_MARGIN,
    LAW_MARGINS,
    TEST_SEED,
    VALIDATION_SEED,
    SavedPolicy,
    SaveRule,
    ScoringStopped,
    choose_margin,
)
from sim import N_ACTIONS, evaluate, scenario
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


def test_the_validation_trials_are_neither_the_test_trials_nor_the_curve_s() -> None:
    policy = constant(0, version=1)
    test = evaluate(CFG, PolicyController(policy), 20, 100, seed=TEST_SEED).coverage_per_trial
    for seed in (VALIDATION_SEED, 0):
        other = evaluate(CFG, PolicyController(policy), 20, 100, seed=seed).coverage_per_trial
        assert not np.isin(other, test).all()  # other arenas, not the reported ones reordered


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


def test_the_margin_chosen_is_the_best_coverage_whatever_its_spread(monkeypatch: pytest.MonkeyPatch) -> None:
    """Robots per covered target is recorded beside each margin's coverage, and never gates the choice."""
    scored_as = {0.0: (78.0, 1.20), 0.1: (79.0, 1.30), 0.2: (78.5, 1.06), 0.3: (78.5, 1.05), 0.5: (77.0, 1.04)}
    scored_as |= {1.0: (76.0, 1.03), 2.0: (75.0, 1.02)}

    def scored(cfg: Any, controller: Any, *args: Any, **kwargs: Any) -> Any:
        coverage, spread = scored_as[controller.policy.law_margin]
        return SimpleNamespace(coverage_mean=coverage, robots_per_covered_target=spread)

    monkeypatch.setattr(selection, "evaluate", scored)
    choice = choose_margin(CFG, law_or_back(0.25), trials=3, steps=100)
    assert choice.margin == 0.1  # the thickest team, and the most covering
    assert choice.scores == {m: c for m, (c, _) in scored_as.items()}
    assert choice.spreads == {m: r for m, (_, r) in scored_as.items()}


def test_the_rule_saves_the_last_tables_read_with_the_margin_chosen_given_or_none() -> None:
    last = dataclasses.replace(law_or_back(0.25), version=7)
    chosen, saved = SaveRule(CFG, law_margin=None, trials=3, steps=100).decide(last, at=42.0)
    assert chosen.version == 7 and np.array_equal(chosen.tables, last.tables)  # the same tables, only read
    assert saved.margin == chosen.law_margin == choose_margin(CFG, last, 3, 100).margin == 0.3
    assert saved.choice is not None and saved.choice.scores == choose_margin(CFG, last, 3, 100).scores
    assert (saved.version, saved.at_s) == (7, 42.0)
    given, record = SaveRule(CFG, law_margin=0.1, trials=3, steps=100).decide(last, at=1.0)
    assert given.law_margin == record.margin == 0.1 and record.choice is None
    compass = Policy(
        formulation=FORMULATIONS["paper"],
        discretization=Discretization.from_per_action([np.zeros((1, FORMULATIONS["paper"].dim), np.float32)] * 8),
        tables=np.zeros((1, 8), np.float32),
        robot_table=np.zeros(CFG.n_robots, np.int64),
        version=3,
    )
    same, plain = SaveRule(CFG, law_margin=None, trials=3, steps=100).decide(compass, at=2.0)
    assert same is compass and plain.margin is None and plain.choice is None


def test_a_stopped_choice_saves_the_same_tables_by_the_fallback_and_the_record_round_trips() -> None:
    last = law_or_back(0.25)
    rule = SaveRule(CFG, law_margin=None, trials=3, steps=100)
    stop = threading.Event()
    stop.set()
    with pytest.raises(ScoringStopped):
        rule.decide(last, at=5.0, stop=stop)
    read, saved = rule.fallback(last, at=5.0)
    assert read.law_margin == saved.margin == FALLBACK_MARGIN and saved.choice is None
    assert np.array_equal(read.tables, last.tables) and "stopped" in saved.reason
    _, chosen = rule.decide(last, at=6.0)
    for record in (saved, chosen):
        again = SavedPolicy.from_dict(record.to_dict())
        assert again.to_dict() == record.to_dict()
        assert (again.version, again.margin, again.reason) == (record.version, record.margin, record.reason)


def test_the_decisions_off_law_are_counted_for_a_law_set_only() -> None:
    from algorithm.policy import evaluate_off_law

    runs_away = law_or_back(0.25)
    plain, off = evaluate_off_law(CFG, runs_away, 2, 50, seed=0)
    assert off is not None and off.pct == 100.0 and plain.coverage_mean == coverage_on_two_trials(runs_away)
    assert off.shared_off_pct == (100.0 if off.shared_pct > 0 else 0.0)
    _, off = evaluate_off_law(CFG, dataclasses.replace(runs_away, law_margin=0.3), 2, 50, seed=0)
    assert off is not None and off.pct == 0.0 and off.shared_off_pct == 0.0
    # Half the robots' rows favour back: half the decisions leave law.
    tables = np.concatenate([runs_away.tables, np.zeros_like(runs_away.tables)])
    split = dataclasses.replace(runs_away, tables=tables, robot_table=np.arange(CFG.n_robots) % 2)
    _, off = evaluate_off_law(CFG, split, 2, 50, seed=0)
    assert off is not None and off.pct == 50.0


def test_decisions_where_targets_are_shared_are_counted_from_what_the_robots_see() -> None:
    """The law itself (margin above the gap), over 20 trials: the share of decisions taken where a teammate also
    watched one of the robot's targets is the share of robot-steps where ``n_seen > n_only``, as the world says."""
    from algorithm.policy import TALLY

    policy = dataclasses.replace(law_or_back(0.25), law_margin=0.3)
    steps, seen = [0, 0], []

    def count(world: Any, obs: Any) -> None:
        steps[0] += obs.n_seen.size
        steps[1] += int((obs.n_seen > obs.n_only).sum())

    controller = PolicyController(policy, tally=np.zeros(TALLY, np.int64))
    evaluate(CFG, controller, 4, 60, seed=0, on_step=count)
    seen.append(controller.off_law())
    off = seen[0]
    assert off is not None and off.pct == 0.0 and 0.0 < off.shared_pct < 100.0
    # Decisions are taken every step by this policy (act_every 1), on the observation before the step: the shares
    # agree to within one step of the trial's.
    assert abs(off.shared_pct - 100.0 * steps[1] / steps[0]) < 100.0 / 60


def coverage_on_two_trials(policy: Policy) -> float:
    return evaluate(CFG, PolicyController(policy), 2, 50, seed=0).coverage_mean
