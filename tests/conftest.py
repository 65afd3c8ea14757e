"""Hooks of the whole suite: the order of the tests for ``make test``'s pytest-xdist workers.

``make test`` runs the suite on two workers (``TEST_WORKERS``) with ``--dist worksteal``, which first hands each
worker one contiguous share of the collection, in order, then lets an idle worker take the second half of the longest
queue. The end-to-end tests (marked ``slow``) take 10-120 s each and most of the suite's time; the others milliseconds
to seconds. So the collection is laid out as those shares: the slow tests dealt longest first, each to the share with
the least work so far, each share starting with its slow tests and filled up with short ones. Every worker then starts
on its longest test at once, and the short ones fill the gaps (with the slow tests left in one queue, one worker ended
alone on the last of them, minutes after the others). Without xdist the slow tests simply come first.
"""

from __future__ import annotations

import os

import pytest

SLOW_SECONDS = {
    "test_chaos_applies_every_fault_and_the_contract_holds": 119,
    "test_a_killed_learner_actor_and_router_come_back_and_the_run_ends_exactly": 133,
    "test_a_training_job_survives_a_killed_actor_task_and_a_requeue": 82,
    "test_up_saves_one_recording_of_every_process": 71,
    "test_learner_restarted_with_resume_continues_and_outboxes_fill_the_gap": 69,
    "test_a_secure_run_stopped_mid_training_resumes_over_tls_and_trains_only_what_was_left": 69,
    "test_experience_flows_versions_advance_late_actor_and_killed_actor": 67,
    "test_learner_killed_just_after_a_checkpoint_resumes_exactly": 62,
    "test_sigterm_during_phase_1_then_resume_keeps_every_acknowledged_tuple": 59,
    "test_sigterm_to_a_serial_run_winds_it_down_to_its_report_too": 52,
}
"""The longest tests' seconds with three workers on 2 cores (2026-12-03); other slow tests count as
:data:`SLOW_DEFAULT_S`. Only the order depends on these: a wrong figure costs time, never a result."""
SLOW_DEFAULT_S = 20


def cost(item: pytest.Item) -> float:
    return SLOW_SECONDS.get(getattr(item, "originalname", item.name), SLOW_DEFAULT_S)


def shares(slow: list[pytest.Item], fast: list[pytest.Item], workers: int) -> list[pytest.Item]:
    """The collection in ``workers`` contiguous shares of the sizes worksteal deals (each the rest // the workers
    left), the slow tests spread over them longest first onto the least loaded share."""
    total, sizes = len(slow) + len(fast), []
    for k in range(workers):
        sizes.append((total - sum(sizes)) // (workers - k))
    loads, dealt = [0.0] * workers, [[] for _ in range(workers)]
    for item in sorted(slow, key=cost, reverse=True):
        open_shares = [k for k in range(workers) if len(dealt[k]) < sizes[k]]
        k = min(open_shares, key=lambda k: loads[k])
        dealt[k].append(item)
        loads[k] += cost(item)
    order: list[pytest.Item] = []
    rest = iter(fast)
    for k in range(workers):
        order += dealt[k] + [next(rest) for _ in range(sizes[k] - len(dealt[k]))]
    return order


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    slow = [item for item in items if item.get_closest_marker("slow") is not None]
    fast = [item for item in items if item.get_closest_marker("slow") is None]
    # Every worker collects and orders the suite itself (xdist insists the orders agree): it reads the count here.
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    items[:] = shares(slow, fast, workers) if workers > 1 else sorted(slow, key=cost, reverse=True) + fast
