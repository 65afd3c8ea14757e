"""The learner's watcher: what it sends the monitor and on which learner_step, and nothing at all when monitoring is
off (not even the work of preparing it)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from algorithm.discretization import Discretization
from algorithm.policy import Policy
from learner.report import LearnerStatus
from monitor import Monitor
from monitor.learner import LearnerWatch
from sim import FORMULATIONS, scenario


class Recorder(Monitor):
    """An enabled monitor that keeps every call: (method, keyword arguments)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, dict[str, Any]]] = []

    @property
    def enabled(self) -> bool:
        return True

    def __getattribute__(self, name: str) -> Any:
        if name == "enabled" or name.startswith("_") or name not in Monitor.__dict__:
            return object.__getattribute__(self, name)
        calls = object.__getattribute__(self, "calls")
        return lambda *args, **kwargs: calls.append((name, {"args": args, **kwargs}))

    def names(self) -> list[str]:
        return [name for name, _ in self.calls]


def policy(version: int) -> Policy:
    disc = Discretization.from_per_action([np.zeros((1, 6), np.float32)] * 8)
    tables = np.arange(20, dtype=np.float32).reshape(10, 2).repeat(4, axis=1)
    return Policy(FORMULATIONS["paper"], disc, tables, np.arange(10), 5, version=version)


def test_status_publishes_are_learner_steps_and_a_new_actor_gets_a_layout() -> None:
    recorder = Recorder()
    watch = LearnerWatch(recorder, scenario(), clock=lambda: 0.0)
    status = LearnerStatus(policy_version=3, live_actors=2, store_size=10, tuples_per_s=5.0, rejected=1)
    watch.status(status, actors=["a0"], lag={"a0": 1})
    watch.status(status, actors=["a0"], lag={"a0": 0})
    spread = {"learned": {"only_shared_pct": 40.0, "none_in_view_pct": 10.0, "robots_per_covered_target": 1.4}}
    watch.evaluated(policy(3), 61.5, spread, trials=10)
    watch.status(status, actors=["a0", "a1"], lag={"a0": 0, "a1": 2})
    comparison = {"learned": spread["learned"], "a-cmommt": {**spread["learned"], "learned_minus": -2.0}}
    watch.final(policy(4), 63.0, 50, comparison)
    assert [name for name in recorder.names() if name != "use_clock"] == [
        "send_blueprint",
        "learner_metrics",
        "learner_metrics",
        "eval_coverage",
        "cooperation",
        "prototypes",
        "q_stats",
        "send_blueprint",
        "learner_metrics",
        "final_coverage",
        "cooperation",
        "prototypes",
        "q_stats",
    ]
    calls = [kw for name, kw in recorder.calls if name != "use_clock"]
    assert [calls[i]["learner_step"] for i in (1, 2, 3, 4, 8, 9, 10)] == [1, 2, 2, 2, 3, 3, 3]
    assert calls[0]["args"] == (["a0"],) and calls[7]["args"] == (["a0", "a1"],)
    assert calls[8]["lag"] == {"a0": 0, "a1": 2} and calls[8]["rejected"] == 1
    assert calls[9]["trials"] == 50 and calls[9]["policy_version"] == 4 and calls[9]["args"] == (63.0,)
    assert calls[4]["args"] == (spread,) and calls[4]["trials"] == 10
    assert calls[10]["args"] == (comparison,) and calls[10]["trials"] == 50


def test_started_names_the_curve_and_measures_the_references_once() -> None:
    recorder = Recorder()
    measured: list[int] = []

    def references() -> Mapping[str, float]:
        measured.append(1)
        return {"random": 16.5}

    frame = FORMULATIONS["frame-difference"]
    LearnerWatch(recorder, scenario(), clock=lambda: 0.0).started(frame, references)
    assert recorder.calls[1:] == [
        ("formulation", {"args": (frame,)}),
        ("reference_levels", {"args": ({"random": 16.5},)}),
    ]
    assert measured == [1]


def test_off_it_does_nothing_not_even_the_measurements() -> None:
    def references() -> Mapping[str, float]:
        raise AssertionError("measured with monitoring off")

    watch = LearnerWatch(Monitor(), scenario(), clock=lambda: 0.0)
    watch.started(FORMULATIONS["paper"], references)
    watch.status(LearnerStatus(), actors=["a0"], lag={})
    broken = policy(1)
    object.__setattr__(broken, "discretization", None)  # any use of it would raise
    watch.evaluated(broken, 50.0, {}, trials=10)
    watch.final(broken, 50.0, 50, {})
    assert watch.step == 0


@pytest.mark.parametrize("scale", [None, 150.0])
def test_prototypes_are_drawn_in_arena_units_whatever_the_fit_standardized(scale: float | None) -> None:
    recorder = Recorder()
    p = policy(2)
    stored = np.arange(48, dtype=np.float32).reshape(8, 6)  # arena units, as a discretization keeps them
    disc = p.discretization
    object.__setattr__(
        p,
        "discretization",
        Discretization(stored, disc.labels, disc.offsets, None if scale is None else np.full(6, scale)),
    )
    LearnerWatch(recorder, scenario(), clock=lambda: 0.0).policy(p)
    ((_, drawn),) = [(n, kw) for n, kw in recorder.calls if n == "prototypes"]
    np.testing.assert_allclose(np.concatenate(drawn["args"][0]), stored, rtol=1e-6)
    np.testing.assert_allclose(np.concatenate(drawn["args"][1]), p.tables.mean(axis=0))
