"""Progress on stderr: plain lines with the figures off a terminal, a tqdm bar on one, stdout left alone."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest

from ennc_ql.cli import main
from learner.report import LearnerStatus
from tests.fakes import TINY
from tools.cluster import cluster_status
from tools.progress import ProgressBar, plain_line
from tools.sweeps.reproduce import reproduce


def counters(**figures: float) -> dict[str, float]:
    """The learner's status counters as a Status message carries them (learner.report.LearnerStatus); ``coverage``
    only once an evaluation ran."""
    base = {
        "tuples_received": 0.0,
        "store_size": 0.0,
        "overwritten": 0.0,
        "duplicates": 0.0,
        "gaps": 0.0,
        "policy_version": 0.0,
        "live_actors": 2.0,
        "tuples_per_s": 0.0,
        "policy_lag_max": 0.0,
        "rejected": 0.0,
        "fits": 0.0,
        "elapsed": 0.0,
    }
    return {**base, **figures}


def test_cluster_status_while_exploring() -> None:
    line = cluster_status(
        LearnerStatus.from_counters(counters(tuples_received=1_234_567, tuples_per_s=250_400.0, elapsed=35.0))
    )
    assert line == "exploring: 1,234,567 tuples (250 k/s), policy v0, 2 actors, coverage –"


def test_cluster_status_in_phase_2() -> None:
    line = cluster_status(
        LearnerStatus.from_counters(
            counters(tuples_received=9e6, tuples_per_s=31_000.0, policy_version=12, coverage=57.25)
        )
    )
    assert line == "phase 2: 9,000,000 tuples (31 k/s), policy v12, 2 actors, coverage 57.2%"


def test_plain_line_shows_position_and_status() -> None:
    assert plain_line("up", 35.4, 480.0, "s", "exploring") == "up [35/480 s] exploring"
    assert plain_line("reproduce", 3, 12, "jobs", "") == "reproduce [3/12 jobs]"


def test_off_a_terminal_live_figures_are_rate_limited_and_milestones_are_not() -> None:
    stream = io.StringIO()
    with ProgressBar("up", total=480, unit="s", every=3600, stream=stream) as bar:
        assert not bar.tty
        bar.show(5, cluster_status(LearnerStatus.from_counters(counters(tuples_received=1000, tuples_per_s=200.0))))
        bar.show(
            6, cluster_status(LearnerStatus.from_counters(counters(tuples_received=2000, tuples_per_s=300.0)))
        )  # within `every`: no line
        bar.mark("evaluation: policy v3 observes 55.1% of targets", n=40)
    assert stream.getvalue().splitlines() == [
        "up [5/480 s] exploring: 1,000 tuples (0 k/s), policy v0, 2 actors, coverage –",
        "up [40/480 s] evaluation: policy v3 observes 55.1% of targets",
    ]


def test_off_a_terminal_every_show_prints_once_the_interval_passed() -> None:
    stream = io.StringIO()
    with ProgressBar("bench sim", total=2, unit="runs", every=0.0, stream=stream) as bar:
        bar.show(status="random, 256 arenas")
        bar.show(1, "a-cmommt, 256 arenas")
    assert stream.getvalue().splitlines() == [
        "bench sim [0/2 runs] random, 256 arenas",
        "bench sim [1/2 runs] a-cmommt, 256 arenas",
    ]


def test_off_a_terminal_the_same_figures_are_not_printed_again() -> None:
    stream = io.StringIO()
    with ProgressBar("up", total=120, unit="s", every=0.0, stream=stream) as bar:
        for _ in range(3):
            bar.show(120, "training over: final evaluation and report")
        bar.show(120, "training over: final evaluation (60%) and report")
        bar.mark("training over: final evaluation and report")  # a milestone is printed whatever came before
    assert stream.getvalue().splitlines() == [
        "up [120/120 s] training over: final evaluation and report",
        "up [120/120 s] training over: final evaluation (60%) and report",
        "up [120/120 s] training over: final evaluation and report",
    ]


def test_on_a_terminal_it_is_a_tqdm_bar_with_the_figures_in_its_postfix() -> None:
    stream = io.StringIO()
    with ProgressBar("up", total=480, unit="s", stream=stream, tty=True) as bar:
        bar.show(35.4, "phase 2: 9,000,000 tuples")
        bar.mark("evaluation: policy v3 observes 55.1% of targets")
    text = stream.getvalue()
    assert "\r" in text  # redrawn in place
    assert "35/480 s" in text and "7%" in text and ", phase 2: 9,000,000 tuples" in text
    assert "up: evaluation: policy v3 observes 55.1% of targets\n" in text  # the milestone stays above the bar


def test_a_stream_that_is_no_terminal_gets_plain_lines() -> None:
    assert not ProgressBar("x", total=1, unit="s", stream=io.StringIO()).tty


def test_bench_progress_goes_to_stderr_and_json_alone_to_stdout(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "sim", "--seconds", "0.02", "--json"]) == 0
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert captured.out.count("\n") == 1
    lines = [line for line in captured.err.splitlines() if line.startswith("bench sim [")]
    assert lines[-1].startswith("bench sim [8/8 runs] a-cmommt, 16384 arenas: ")
    best = out["by_batch_size"]["random"][str(out["arenas"])] / 1e6
    assert f"random, {out['arenas']} arenas: {best:.2f} M robot-steps/s" in captured.err


def test_reproduce_reports_each_finished_job_with_its_coverage(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    report = reproduce(TINY, processes=1, out_dir=tmp_path, methods=["random", "vqql-local-16"])
    coverage = {row["name"]: row["coverage_mean"] for row in report["methods"]}
    # Milestone lines only: a job's name, then its coverage (live lines carry a stage or "latest" in between).
    finished = [
        re.fullmatch(r"reproduce \[(\d)/2 jobs\] ([^ :]+): ([\d.]+)%", line)
        for line in capsys.readouterr().err.splitlines()
    ]
    shown = [(m[1], m[2], float(m[3])) for m in finished if m]
    assert shown == [
        ("1", "vqql-local-16[0]", pytest.approx(coverage["vqql-local-16"], abs=0.01)),
        ("2", "random", pytest.approx(coverage["random"], abs=0.01)),
    ]
