"""The learner's typed figures: "no evaluation yet" is None through the Status counters, not a number."""

from __future__ import annotations

import dataclasses

from learner.report import LearnerStatus


def test_no_coverage_yet_is_no_counter_and_reads_back_as_none() -> None:
    before = LearnerStatus(tuples_received=10, elapsed=3.5)
    counters = before.to_counters()
    assert "coverage" not in counters and counters["tuples_received"] == 10.0
    assert LearnerStatus.from_counters(counters) == before and before.coverage is None


def test_a_coverage_travels_as_a_counter() -> None:
    after = LearnerStatus(policy_version=4, coverage=61.25, scoring=0.5)
    counters = after.to_counters()
    assert counters["coverage"] == 61.25 and counters["scoring"] == 0.5
    assert LearnerStatus.from_counters(counters) == after
    assert set(counters) == {f.name for f in dataclasses.fields(LearnerStatus)}
    # A figure not measured yet (no final evaluation running) stays off the wire; the reader keeps its None.
    training = LearnerStatus(policy_version=4, coverage=61.25)
    assert "scoring" not in training.to_counters()
    assert LearnerStatus.from_counters(training.to_counters()).scoring is None
