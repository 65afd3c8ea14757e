"""Draws of phase 1 (``LearnerConfig.draws``): each fitted afresh on the first fit's tuples, each with its own early
window, the best early candidate over them kept across a resume, and every acknowledged visit still accounted for."""

from __future__ import annotations

import dataclasses
import logging
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from algorithm import phase1 as phase1_module
from algorithm.phase1 import Phase1Config
from algorithm.policy_file import load_policy
from algorithm.transitions import Transitions
from learner.checkpoint import kept_visits
from learner.config import LearnerConfig
from learner.fitting import EXPLORATION, Fitter
from learner.policy_state import PolicyState
from learner.service import DRAWN_POLICY, DRAWS, LearnerService
from protocol import InMemoryBus, InMemoryTransport
from tests.algorithm.test_selection import constant, validation
from tests.fakes import run_with_actor
from tests.learner.test_service import DIM, FAST, PAPER, increment, one_cell_per_action


@pytest.mark.parametrize(
    ("changes", "error"),
    [
        ({"draws": 0}, "draws must be at least 1"),
        ({"draws": 3, "refit_growth": 2.0}, "give draws = 1"),
        ({"refit_growth": 2.0}, "give draws = 1"),  # the default draws
    ],
)
def test_draws_that_cannot_be_made_are_refused(changes: dict[str, Any], error: str) -> None:
    with pytest.raises(ValueError, match=error):
        LearnerConfig(**changes)


@pytest.mark.parametrize(
    ("changes", "drawing"),
    [
        ({}, True),
        ({"draws": 1}, False),
        ({"early_window": 0.0}, False),  # nothing to choose a draw by: one draw, and refits are allowed
        ({"keep_best": False, "refit_growth": 2.0}, False),
    ],
)
def test_a_run_draws_only_with_an_early_candidate_to_choose_by(
    tmp_path: Path, changes: dict[str, Any], drawing: bool
) -> None:
    config = LearnerConfig(**changes)
    assert config.drawing is drawing
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
    assert (service.fitter.exploration is not None) is drawing


def test_a_draw_starts_its_tables_from_its_labels_and_every_acknowledged_visit_stays_accounted_for(
    tmp_path: Path,
) -> None:
    state = PolicyState(n_robots=10, formulation=PAPER, scenario="cmommt-v1", action_steps=5, method="m")
    first = one_cell_per_action()
    state.adopt(first)
    state.publish()  # version 1
    assert state.add_increment(increment("a", 0, [1.0] * 8, [2] * 8, version=1))
    state.publish()  # merged: 16 visits in robot 2's row
    assert state.add_increment(increment("a", 1, [1.0] * 8, [3] * 8, version=2))  # pending: 24 more
    labelled = dataclasses.replace(first, labels=np.arange(8, dtype=first.labels.dtype))
    state.adopt(labelled, fresh=True)
    update = state.publish()  # version 3: the draw's
    assert (update.q_tables == np.arange(8)[None, :]).all() and update.visits.sum() == 0  # nothing carried over
    assert state.dropped_visits == 16 + 24
    assert not state.add_increment(increment("a", 2, [1.0] * 8, [5] * 8, version=2))  # over the old cells: stale
    assert state.add_increment(increment("a", 3, [1.0] * 8, [7] * 8, version=3))
    assert state.dropped_visits == 16 + 24 + 40
    # A checkpoint accounts for every visit acknowledged: 16 + 24 + 40 dropped, 56 pending.
    arrays, meta = state.to_arrays()
    np.savez(tmp_path / "c.npz", **arrays)
    assert kept_visits(tmp_path / "c.npz") == 16 + 24 + 40 + 56
    restored = PolicyState(n_robots=10, formulation=PAPER, scenario="cmommt-v1", action_steps=5, method="m")
    restored.restore(arrays, meta)
    assert restored.dropped_visits == 80


def test_each_closed_window_is_scored_the_best_draw_is_saved_and_resumed_and_a_late_window_is_no_candidate(
    tmp_path: Path,
) -> None:
    config = dataclasses.replace(
        FAST, validation_trials=3, final_eval_trials=3, law_margin=0.0, early_window=30.0, draws=4, duration=200.0
    )
    scores = {a: validation(constant(a, version=1), 3) for a in range(8)}
    ranked = sorted(scores, key=scores.__getitem__)
    bad, good, best = ranked[0], ranked[-2], ranked[-1]
    clock, current = [0.0], [constant(bad, version=2)]
    requested: list[int] = []
    scored: list[int] = []
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service.elapsed = lambda: clock[0]  # type: ignore[method-assign]
        fitter = service.fitter

        def draw(index: int) -> bool:  # the fit runs until the test adopts its discretization
            requested.append(index)
            fitter._thread = threading.Thread()
            fitter._thread.is_alive = lambda: True  # type: ignore[method-assign]
            return True

        fitter.draw = draw  # type: ignore[method-assign]
        fitter.fit_s = 5.0
        score = service._score

        def counted(policy: Any, *stop: Any) -> Any:
            scored.append(policy.version)
            return score(policy, *stop)

        service._score = counted  # type: ignore[method-assign]
        service._adopt(one_cell_per_action(DIM))  # draw 0's window opens at 0 s
        service.state.policy = lambda: current[0]  # type: ignore[method-assign]
        clock[0] = 10.0
        service._offer_early()
        clock[0] = 31.0
        service._offer_early()  # closed: draw 0's candidate scored, draw 1 asked for (31 + 5 + 30 < 200)
        assert scored == [2] and requested == [1]
        service._offer_early()
        assert scored == [2] and requested == [1]  # once each, until the draw is adopted
        clock[0] = 40.0
        fitter._thread = None
        service._adopt(one_cell_per_action(DIM), draw=True)
        current[0] = constant(good, version=3)
        clock[0] = 45.0
        service._offer_early()
        clock[0] = 71.0
        service._offer_early()
        assert scored == [2, 3] and requested == [1, 2]
        assert service._drawn is not None and service._drawn.draw == 1
        # Draw 2's window opens; its candidate scores best on validation, but training stops before the window closes.
        clock[0] = 80.0
        fitter._thread = None
        service._adopt(one_cell_per_action(DIM), draw=True)
        current[0] = constant(best, version=4)
        clock[0] = 85.0
        service._offer_early()
        current[0] = constant(bad, version=5)
        service._evaluate()  # the keeper's only offer: bad, version 5
        service.checkpoint()
        under_way = [service._draw, service._window_scored]
        clock[0] = 200.0  # the loop stops at once
        report = service.run(threading.Event())
    assert under_way == [2, False]
    assert scored == [2, 3, 5]  # the wind-down scored only the kept policy: draw 2's open window is no candidate
    assert [(d["draw"], d["version"], d["validation_coverage"]) for d in report.draws] == [
        (0, 2, round(scores[bad], 3)),
        (1, 3, round(scores[good], 3)),
    ]
    assert [(c["source"], c.get("draw"), c["version"], c["chosen"]) for c in report.candidates] == [
        ("kept", None, 5, False),
        ("early", 1, 3, True),
    ]
    saved, _ = load_policy(tmp_path / "policy.npz")
    assert saved.version == 3 and int(np.argmax(saved.tables[0])) == good
    # Every closed window's candidate is kept as scored (with the run's margin), the open one's is not.
    assert sorted(p.name for p in (tmp_path / DRAWS).iterdir()) == ["draw-0.npz", "draw-1.npz"]
    for index, (version, action) in enumerate([(2, bad), (3, good)]):
        candidate, _ = load_policy(tmp_path / DRAWS / f"draw-{index}.npz")
        assert candidate.version == version and int(np.argmax(candidate.tables[0])) == action
        assert candidate.law_margin == 0.0
    # A resumed learner has the best draw as scored (not scored again), and the draw under way with its window.
    with InMemoryTransport(InMemoryBus()) as t:
        resumed = LearnerService(t, config, tmp_path, resume=True)
    assert resumed._drawn is not None and resumed._drawn.draw == 1 and resumed._drawn.policy.version == 3
    assert resumed._drawn.coverage == service._drawn.coverage and resumed._draw == 2
    assert resumed.draws == report.draws and resumed._window_at == 80.0
    # Its file lost: the scored figures without the policy are no candidate; the run goes on without it.
    (tmp_path / DRAWN_POLICY).unlink()
    with InMemoryTransport(InMemoryBus()) as t:
        forgot = LearnerService(t, config, tmp_path, resume=True)
    assert forgot._drawn is None and forgot._draw == 2


@pytest.mark.parametrize(("law_margin", "read_with"), [(None, 0.3), (1.0, 1.0)])
def test_an_early_window_ranks_its_versions_on_early_trials_read_as_they_will_be(
    tmp_path: Path, law_margin: float | None, read_with: float
) -> None:
    """With the margin chosen at the window's close, the versions are read with ``early_margin``; with one given,
    with that one."""
    config = dataclasses.replace(
        FAST,
        validation_trials=3,
        early_trials=4,
        early_margin=0.3,
        law_margin=law_margin,
        early_window=30.0,
        duration=200.0,
    )
    clock, current = [0.0], [constant(0, version=2)]
    seen: list[tuple[int, float, int]] = []
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service.elapsed = lambda: clock[0]  # type: ignore[method-assign]
        service._adopt(one_cell_per_action(DIM))
        service.state.policy = lambda: current[0]  # type: ignore[method-assign]
        early = service.early
        assert early is not None
        score = early.score
        early.score = lambda p: (seen.append((early.trials, p.law_margin, p.version)), score(p))[1]  # type: ignore[method-assign]
        for at, version in ((10.0, 2), (13.0, 3)):
            clock[0], current[0] = at, constant(version, version=version)
            service._offer_early()
    assert seen == [(4, read_with, 2), (4, read_with, 3)]
    # The window keeps the version as published: its own margin is chosen once the window closes.
    assert service.early.best is not None and service.early.best.policy.law_margin == 0.0


def test_a_negative_early_margin_is_refused() -> None:
    with pytest.raises(ValueError, match="early_margin must be a finite number >= 0"):
        LearnerConfig(early_margin=-0.1)


def _clocked(service: LearnerService) -> tuple[list[float], list[int]]:
    """``service`` on a test clock (the list's one value), its draws only recorded (the list of their indices), a fit
    taken to last 5 s, and draw 0's window opened at 0 s on a constant policy."""
    clock: list[float] = [0.0]
    requested: list[int] = []
    service.elapsed = lambda: clock[0]  # type: ignore[method-assign]
    service.fitter.draw = lambda index: requested.append(index) or True  # type: ignore[method-assign]
    service.fitter.fit_s = 5.0
    service._adopt(one_cell_per_action(DIM))
    service.state.policy = lambda: constant(0, version=2)  # type: ignore[method-assign]
    return clock, requested


def test_no_draw_starts_whose_window_could_not_close_before_the_duration_and_a_late_fit_is_not_adopted(
    tmp_path: Path,
) -> None:
    config = dataclasses.replace(FAST, validation_trials=3, law_margin=0.0, early_window=30.0, draws=4, duration=60.0)
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        clock, requested = _clocked(service)
        clock[0] = 10.0
        service._offer_early()
        clock[0] = 31.0
        service._offer_early()  # 31 + 5 + 30 >= 60: no time for a draw's window
        assert requested == [] and len(service.draws) == 1
        version = service.state.version
        service._stopped_at = 40.0
        service._adopt(one_cell_per_action(DIM), draw=True)  # a fit that ends after training stopped
        assert service._draw == 0 and service.state.version == version


class _Intake:
    """What the fitter reads of an intake: a store of ``n`` tuples of the default formulation."""

    def __init__(self, n: int) -> None:
        rng = np.random.default_rng(7)
        self.data = Transitions(
            robot=rng.integers(0, 10, n).astype(np.int16),
            state=rng.random((n, DIM), dtype=np.float32),
            action=rng.integers(0, 8, n).astype(np.uint8),
            reward=rng.random(n, dtype=np.float32),
            next_state=rng.random((n, DIM), dtype=np.float32),
            done=np.zeros(n, bool),
        )
        self.tuples_received = n

    def __len__(self) -> int:
        return len(self.data)

    def snapshot_for_fit(self) -> tuple[Transitions, int]:
        return self.data, self.tuples_received


def test_a_stop_gives_up_a_windows_scoring_where_an_earlier_draw_is_scored_and_starts_no_draw(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    # The margin is chosen (law_margin none): a window's scoring is seven margins' validation trials, which a SIGTERM's
    # grace cannot wait for on top of the wind-down's own.
    config = dataclasses.replace(
        FAST, validation_trials=3, margin_trials=3, law_margin=None, early_window=30.0, draws=4, duration=200.0
    )
    stop = threading.Event()
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service._stop = stop
        clock, requested = _clocked(service)
        clock[0] = 10.0
        service._offer_early()
        stop.set()
        clock[0] = 31.0
        service._offer_early()  # the first draw's window is scored (the wind-down would score it), no draw starts
        assert requested == [] and [d["draw"] for d in service.draws] == [0] and service._window_scored
        stop.clear()
        service._offer_early()
        assert requested == [1]
        clock[0] = 36.0
        service._adopt(one_cell_per_action(DIM), draw=True)  # draw 1's window opens at 36 s
        service.state.policy = lambda: constant(1, version=4)  # type: ignore[method-assign]
        clock[0] = 40.0
        service._offer_early()
        stop.set()
        clock[0] = 67.0
        with caplog.at_level(logging.INFO, logger="learner.service"):
            service._offer_early()
        assert "draw 1: training stopped while its candidate was scored" in [r.getMessage() for r in caplog.records]
        assert requested == [1] and [d["draw"] for d in service.draws] == [0] and not service._window_scored
        assert sorted(p.name for p in (tmp_path / DRAWS).iterdir()) == ["draw-0.npz"]
        assert service._early_candidate() is service._drawn is not None and service._drawn.draw == 0


def test_every_draw_fits_the_first_fits_tuples_with_its_own_seed_also_after_a_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    fits: list[tuple[int, int]] = []
    real = phase1_module.phase1

    def recorded(data: Any, *args: Any, seed: int, **kwargs: Any) -> Any:
        fits.append((len(data), seed))
        return real(data, *args, seed=seed, **kwargs)

    monkeypatch.setattr("learner.fitting.phase1", recorded)
    config = dataclasses.replace(FAST, min_tuples=2000, draws=3)
    adopted: list[bool] = []
    fitter = Fitter(config, lambda disc, draw: adopted.append(draw), exploration=tmp_path / EXPLORATION)
    fitter.poll(_Intake(2500), None)  # type: ignore[arg-type]
    fitter.join()
    assert fitter.draw(1)
    fitter._thread.join()  # type: ignore[union-attr]
    # A resumed learner's fitter has the tuples from the run folder only.
    again = Fitter(config, lambda disc, draw: adopted.append(draw), exploration=tmp_path / EXPLORATION)
    assert again.draw(1)
    again._thread.join()  # type: ignore[union-attr]
    assert adopted == [False, True, True] and [n for n, _ in fits] == [2500] * 3
    assert fits[1][1] == fits[2][1] != fits[0][1]  # draw 1's seed, the same after a resume
    assert fitter.fit_s > 0
    # The tuples lost: no draw, said once.
    (tmp_path / EXPLORATION).unlink()
    lost = Fitter(config, lambda disc, draw: adopted.append(draw), exploration=tmp_path / EXPLORATION)
    with caplog.at_level(logging.WARNING, logger="learner.fitting"):
        assert not lost.draw(2) and not lost.draw(2)
    assert [r.getMessage() for r in caplog.records].count(
        f"no more draws: the first fit's tuples are not kept ({tmp_path / EXPLORATION})"
    ) == 1


@pytest.mark.slow
def test_the_end_stops_a_draw_under_way_at_its_next_actions_fit_but_lets_a_first_fit_finish(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    real = phase1_module.phase1
    inside, calls = threading.Event(), [0]

    def endless(data: Any, *args: Any, progress: Any, **kwargs: Any) -> Any:
        """A draw's phase 1 that only ends when a progress call raises (it gives up after 10^5 calls)."""
        inside.set()
        for _ in range(100_000):
            calls[0] += 1
            progress(1, calls[0] % 8)
            threading.Event().wait(0.001)
        return real(data, *args, progress=progress, **kwargs)

    config = dataclasses.replace(FAST, min_tuples=2000, draws=3)
    adopted: list[bool] = []
    fitter = Fitter(config, lambda disc, draw: adopted.append(draw), exploration=tmp_path / EXPLORATION)
    fitter.poll(_Intake(2500), None)  # type: ignore[arg-type]
    fitter.join()  # the first fit is not a draw: it finishes and is adopted
    assert adopted == [False] and fitter.fits == 1
    monkeypatch.setattr("learner.fitting.phase1", endless)
    assert fitter.draw(1)
    assert inside.wait(60)
    with caplog.at_level(logging.INFO, logger="learner.fitting"):
        fitter.join()
    assert not fitter.busy and adopted == [False] and fitter.fits == 1
    assert 0 < calls[0] < 100_000
    messages = [r.getMessage() for r in caplog.records]
    assert "a draw under way is stopped" in messages
    assert any(m.startswith("the draw under way stopped after") for m in messages)


def test_a_learner_with_actors_runs_its_draws_each_on_new_cells_of_the_first_fits_tuples(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fitted: list[int] = []
    real = phase1_module.phase1

    def recorded(data: Any, *args: Any, **kwargs: Any) -> Any:
        fitted.append(len(data))
        return real(data, *args, **kwargs)

    monkeypatch.setattr("learner.fitting.phase1", recorded)
    config = dataclasses.replace(
        FAST,
        min_tuples=6000,
        phase1=Phase1Config(max_iterations=1, n_cycles=15, max_patterns=600),
        broadcast_interval=0.3,
        validation_trials=2,
        margin_trials=2,
        eval_steps=50,
        law_margin=0.0,
        early_window=1.0,
        draws=3,
    )
    bus = InMemoryBus()
    with InMemoryTransport(bus) as lt, InMemoryTransport(bus) as at:
        service = LearnerService(lt, config, tmp_path)
        report = run_with_actor(service, lt, at, lambda: len(service.draws) >= 3)
    assert [d["draw"] for d in report.draws] == [0, 1, 2] and report.phase1_fits == 3
    assert len(set(fitted)) == 1  # every draw on the first fit's tuples, though the store grew meanwhile
    assert (tmp_path / EXPLORATION).exists()
    versions = [d["version"] for d in report.draws]
    assert versions == sorted(versions) and len(set(versions)) == 3
    assert (
        report.candidates
        and report.candidates[1]["draw"] == max(report.draws, key=lambda d: d["validation_coverage"])["draw"]
    )


def test_a_checkpoint_written_before_the_draws_resumes_as_its_first_draw(tmp_path: Path) -> None:
    from learner.checkpoint import Checkpointer

    config = dataclasses.replace(FAST, validation_trials=3, law_margin=0.0, early_window=30.0)
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)
        service._adopt(one_cell_per_action(DIM))
        service.checkpoint()
    checkpointer = Checkpointer(tmp_path)
    arrays, meta = checkpointer.load()
    meta["first_policy_at"] = meta.pop("window_at")
    del meta["draws"], meta["fit_s"]
    arrays.pop("dropped_visits")
    checkpointer.save(arrays, meta)
    with InMemoryTransport(InMemoryBus()) as t:
        resumed = LearnerService(t, config, tmp_path, resume=True)
    assert resumed._window_at == service._window_at is not None
    assert resumed._draw == 0 and not resumed._window_scored and resumed._drawn is None and resumed.draws == []
    assert resumed.state.dropped_visits == 0 and resumed.fitter.fit_s == 0.0


@pytest.mark.parametrize(("cap", "saved"), [("a-cmommt", 3), (None, 4)])
def test_under_a_spread_cap_the_draw_and_the_saved_policy_are_the_best_within_it_also_after_a_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, cap: str | None, saved: int
) -> None:
    # Each version's (coverage %, robots per covered target) on the margin's validation trials, the cap 1.06: draw 0
    # covers more than draw 1 but crowds; draw 2 covers most and crowds; the kept policy (5) crowds too.
    figures = {2: (80.0, 1.09), 3: (79.0, 1.05), 4: (81.0, 1.07), 5: (79.5, 1.08)}
    caps: list[str] = []
    monkeypatch.setattr("learner.service.reference_spread", lambda cfg, name, *a, **k: caps.append(name) or 1.06)
    config = dataclasses.replace(
        FAST, validation_trials=3, early_trials=3, law_margin=0.0, early_window=30.0, draws=3, duration=200.0
    )
    config = dataclasses.replace(config, spread_cap=cap)
    with InMemoryTransport(InMemoryBus()) as t:
        service = LearnerService(t, config, tmp_path)

        def scored(policy: Any, *stop: Any) -> tuple[float, None, float]:
            coverage, spread = figures[policy.version]
            return coverage, None, spread

        service._score = scored  # type: ignore[method-assign]
        clock, requested = _clocked(service)
        for draw, version in enumerate((2, 3, 4)):
            if draw:
                clock[0] = 40.0 * draw
                service._adopt(one_cell_per_action(DIM), draw=True)
            service.state.policy = lambda v=version: constant(v, version=v)  # type: ignore[method-assign]
            clock[0] = 40.0 * draw + 10.0
            service._offer_early()
            clock[0] = 40.0 * draw + 31.0
            service._offer_early()
        assert requested == [1, 2] and service._drawn is not None
        assert service._drawn.draw == (1 if cap else 2)
        service.state.policy = lambda: constant(5, version=5)  # type: ignore[method-assign]
        service._evaluate()
        clock[0] = 200.0
        report = service.run(threading.Event())
    assert caps == ([cap] if cap else [])  # the reference scored once, at the first choice
    assert [(d["draw"], d["validation_coverage"], d["robots_per_covered_target"]) for d in report.draws] == [
        (0, 80.0, 1.09),
        (1, 79.0, 1.05),
        (2, 81.0, 1.07),
    ]
    assert [(c["source"], c["version"], c["chosen"]) for c in report.candidates] == [
        ("kept", 5, False),
        ("early", saved, True),
    ]
    assert load_policy(tmp_path / "policy.npz")[0].version == saved
    assert report.spread_cap == (
        None if cap is None else {"reference": cap, "robots_per_covered_target": 1.06, "validation_trials": 3}
    )
    # A resumed learner knows the best draw's spread, so a later draw is ranked against it as the first one was.
    with InMemoryTransport(InMemoryBus()) as t:
        resumed = LearnerService(t, config, tmp_path, resume=True)
    assert resumed._drawn is not None and resumed._drawn.spread == figures[saved][1]


def test_a_best_draw_checkpointed_before_the_spreads_were_recorded_resumes_with_its_spread_unknown() -> None:
    from learner.service import _Scored

    # As a checkpoint of the twenty-seventh session holds it: no spread, no margins' spreads.
    meta = {
        "source": "early",
        "at": 52.1,
        "coverage": 78.25,
        "margin": {"margin": 1.0, "scores": [[0.5, 78.6], [1.0, 78.25]], "trials": 300, "seed": 1000},
        "draw": 1,
    }
    scored = _Scored.from_meta(meta, constant(1, version=14))
    assert scored.spread is None and scored.margin is not None
    assert scored.margin.spreads == {}
    assert scored.margin.scores == {0.5: 78.6, 1.0: 78.25} and scored.draw == 1
    # Unknown is not within a cap: a later draw known to be within it is preferred, with less coverage.
    assert scored.rank(1.06) < (True, 77.0) and scored.rank(None) == (True, 78.25)
    assert _Scored.from_meta(scored.to_meta(), scored.policy) == scored
