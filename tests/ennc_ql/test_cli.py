"""The ``ennc-ql`` command line: eval and bench print what the library measures."""

from __future__ import annotations

import dataclasses
import json
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ennc_ql.cli import main
from monitor import paths, summarize_recording
from sim import HAND_MADE, evaluate, scenario
from tests.monitor.rrd import rows


def run_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    assert main(list(argv)) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1  # exactly one JSON object on stdout
    return json.loads(out)


@pytest.mark.parametrize("policy", sorted(HAND_MADE))
def test_eval_json_reports_the_library_result(capsys: pytest.CaptureFixture[str], policy: str) -> None:
    out = run_json(capsys, "eval", "--policy", policy, "--trials", "3", "--steps", "150", "--seed", "4", "--json")
    expected = evaluate(scenario(), HAND_MADE[policy], trials=3, steps=150, seed=4)
    assert out["policy"] == policy and out["scenario"] == "cmommt-v1"
    assert (out["trials"], out["steps"], out["seed"]) == (3, 150, 4)
    np.testing.assert_allclose(out["coverage_per_trial"], expected.coverage_per_trial, atol=1e-4)
    assert out["coverage_mean"] == pytest.approx(np.mean(out["coverage_per_trial"]), abs=1e-3)
    assert out["coverage_std"] == pytest.approx(np.std(out["coverage_per_trial"]), abs=1e-3)


def test_eval_table_lists_every_trial(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", "--policy", "random", "--trials", "4", "--steps", "50"]) == 0
    text = capsys.readouterr().out
    assert sum(line.strip().startswith("trial") for line in text.splitlines()) == 4
    assert "mean" in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["eval", "--trials", "0"], "positive integer"),
        (["eval", "--steps", "x"], "positive integer"),
        (["eval", "--scenario", "nope"], "--scenario: unknown value 'nope' (one of cmommt-v1)"),
        (["bench", "everything"], "unknown command 'everything' (one of sim, ennc,"),
    ],
)
def test_bad_flags_get_a_clear_error(capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["eval", "--policy", "greedy"], "--policy: unknown policy 'greedy' (one of random, local, a-cmommt,"),
        (["eval", "--policy", "a-cmomt"], "--policy: unknown policy 'a-cmomt'; did you mean 'a-cmommt'? (one of"),
        (["eval", "--against", "forcerecall"], "--against: unknown policy 'forcerecall'; did you mean 'force-recall'?"),
        (["eval", "--policy", "runs/x/policy.npz"], "--policy runs/x/policy.npz: no such policy file"),
    ],
)
def test_unknown_policy_is_named_with_the_closest_and_the_choices(
    capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"ennc-ql eval: error: {message}"), line
    if "unknown policy" in message:  # every choice listed, and a file named as the other way
        assert line.endswith("a-cmommt-oracle, or a policy file)"), line


def test_bench_sim_reports_measured_rates(capsys: pytest.CaptureFixture[str]) -> None:
    out = run_json(capsys, "bench", "sim", "--seconds", "0.05", "--json")
    assert set(out["robot_steps_per_s"]) == {"random", "a_cmommt"}
    assert all(rate > 0 for rate in out["robot_steps_per_s"].values())
    best = out["by_batch_size"]["random"][str(out["arenas"])]
    assert out["robot_steps_per_s"]["random"] == max(out["by_batch_size"]["random"].values()) == best
    assert (out["robots"], out["targets"]) == (10, 10)


def test_console_script_runs_as_a_process() -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ennc_ql.cli",
            "eval",
            "--policy",
            "a-cmommt",
            "--trials",
            "2",
            "--steps",
            "100",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    out = json.loads(proc.stdout)
    assert len(out["coverage_per_trial"]) == 2
    assert 0.0 < out["coverage_mean"] <= 100.0


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["actor", "--actor-id", "a/b"], "actor_id: 'a/b' is not"),
        (["actor", "--actor-id", "a0", "--learn", "5-2"], "bad robot range"),
        (["actor", "--actor-id", "a0", "--arenas", "0"], "arenas must be at least 1, got 0"),
        (["actor", "--actor-id", "a0", "--arenas", "x"], "--arenas"),
        (["learner", "--run-dir", "x", "--min-tuples", "-3"], "min_tuples must be at least 1, got -3"),
        (["learner", "--run-dir", "x", "--phase1-n-cycles", "0"], "phase1: n_cycles"),
        (["learner", "--run-dir", "x", "--featurizer", "raw"], "--featurizer: unknown value 'raw' (one of local2d,"),
        (["actor", "--formulation", "best"], "--formulation: unknown value 'best' (one of paper, shared-difference"),
        (["actor", "--reward", "money"], "--reward: unknown value 'money' (one of paper, observed, eq2"),
        (["up", "--actor-arenas", "-5"], "arenas must be at least 1, got -5"),
        (["up", "--actors", "0"], "actors must be at least 1"),
        (["learner", "--run-dir", "x", "--mode", "satellite"], "--mode: unknown value 'satellite'"),
        (["learner"], "--run-dir"),
    ],
)
def test_process_flags_are_checked(capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


def test_up_rejects_a_bad_child_value_before_anything_starts(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["up", "--actor-arenas", "-5", "--runs", str(tmp_path)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["ennc-ql up: error: actor: arenas must be at least 1, got -5"]
    assert list(tmp_path.iterdir()) == []  # no run folder, no process


def test_config_file_unknown_key_is_named(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "learner.toml"
    path.write_text("min_tuples = 5000\n[phase1]\nn_cycle = 10\n")
    with pytest.raises(SystemExit) as exc:
        main(["learner", "--config", str(path), "--run-dir", str(tmp_path / "run")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "unknown key 'phase1.n_cycle'" in err and "n_cycles" in err and "Traceback" not in err


def test_unwritable_run_dir_is_one_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(SystemExit) as exc:
        main(["learner", "--run-dir", str(blocker / "run"), "--listen", "tcp/127.0.0.1:0", "--duration", "1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"ennc-ql learner: error: --run-dir {blocker / 'run'}: {blocker} is a file, not a folder"]


def test_resume_without_a_checkpoint_is_a_clear_error(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    with pytest.raises(SystemExit):
        main(["learner", "--run-dir", str(tmp_path), "--resume", "--listen", "tcp/127.0.0.1:0", "--duration", "1"])
    assert "no checkpoint" in capsys.readouterr().err


def test_actor_for_a_robot_that_does_not_exist_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["actor", "--actor-id", "a0", "--learn", "12", "--listen", "tcp/127.0.0.1:0", "--duration", "1"])
    assert "robots (12,) do not all exist" in capsys.readouterr().err


def test_eval_records_the_chosen_trial_for_replay(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "trial.rrd"
    argv = ["eval", "--policy", "a-cmommt", "--trials", "3", "--steps", "40", "--json", "--record-trial", "2"]
    out = run_json(capsys, *argv, "--rerun", "save", str(path))
    assert summarize_recording(path)["rows_per_entity"][f"{paths.EVAL_ARENA}/{paths.ARENA_TARGETS}"] == 40
    coverage = [value[0] for _, value in rows(path, paths.EVAL_COVERAGE, "Scalars:scalars", paths.SIM_STEP)]
    assert len(coverage) == 40
    # The recorded trial is trial 2 as scored: its per-step coverage averages to its metric A.
    assert np.mean(coverage) == pytest.approx(out["coverage_per_trial"][2], abs=1e-3)


def test_eval_refuses_to_record_a_trial_it_does_not_run(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    argv = ["eval", "--trials", "3", "--steps", "10", "--record-trial", "3", "--rerun", "save", str(tmp_path / "x.rrd")]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and list(tmp_path.iterdir()) == []
    assert capsys.readouterr().err == "ennc-ql eval: error: --record-trial 3: only trials 0 to 2 run (--trials)\n"


def test_eval_reads_a_policy_with_the_law_margin_given_and_names_it(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from algorithm.policy import PolicyController
    from algorithm.policy_file import save_policy
    from algorithm.selection import TEST_SEED
    from tests.algorithm.test_selection import law_or_back

    policy = law_or_back(0.25)  # argmax: back everywhere; a margin of 0.3 reads the law
    path = str(save_policy(policy, scenario(), tmp_path / "p.npz"))
    argv = ["eval", "--policy", path, "--trials", "3", "--steps", "150", "--json"]
    plain, margin = run_json(capsys, *argv), run_json(capsys, *argv, "--law-margin", "0.3")
    assert (plain["law_margin"], margin["law_margin"]) == (0.0, 0.3)
    assert (plain["off_law_pct"], margin["off_law_pct"]) == (100.0, 0.0)
    law = evaluate(scenario(), PolicyController(dataclasses.replace(policy, law_margin=0.3)), 3, 150, seed=TEST_SEED)
    np.testing.assert_allclose(margin["coverage_per_trial"], law.coverage_per_trial, atol=1e-4)
    assert margin["coverage_mean"] > plain["coverage_mean"] + 10
    for bad, message in [("a-cmommt", "is a hand-made controller"), (path, None)]:
        extra = ["--law-margin", "-1"] if message is None else ["--law-margin", "0.3"]
        with pytest.raises(SystemExit) as exc:
            main(["eval", "--policy", bad, *extra])
        assert exc.value.code == 2
        assert (message or "expected a finite number of 0 or more") in capsys.readouterr().err


def test_an_unknown_flag_before_the_command_is_named_with_where_the_flags_are(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """Not "which command?": argparse misses the command before it looks at the flag."""
    with pytest.raises(SystemExit) as exc:
        main(["--bogus"])
    assert exc.value.code == 2
    assert capsys.readouterr().err.splitlines() == [
        "ennc-ql: error: unknown option '--bogus'",  # nothing like --verbose once the dashes every flag has are off
        "usage: ennc-ql [OPTIONS] COMMAND  (all options: ennc-ql --help)",
    ]


def test_up_runs_at_most_four_actors_per_core_and_says_so(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from ennc_ql.up import check_actors

    cores = len(os.sched_getaffinity(0))
    check_actors(4 * cores)  # the cap itself is allowed
    with pytest.raises(SystemExit) as exc:
        main(["up", "--actors", str(4 * cores + 1), "--runs", str(tmp_path)])
    assert exc.value.code == 2 and list(tmp_path.iterdir()) == []
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(
        f"ennc-ql up: error: --actors {4 * cores + 1}: up runs at most {4 * cores} actors on this machine (4 per core, "
        f"{cores} core"
    )
    assert line.endswith("(ennc-ql slurm train, or ennc-ql actor on each)")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_the_router_stopped_by_a_signal_closes_and_exits_0_as_learner_and_actor_do(signum: int) -> None:
    """A signal is how the process commands (learner, actor, router) are stopped, by a person or by up: a clean stop,
    status 0. Only up, which a signal keeps from finishing its run, exits 128 + the signal."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ennc_ql.cli", "router", "--listen", "tcp/127.0.0.1:0", "--no-multicast-scouting"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stderr is not None
    try:
        said, deadline = "", time.monotonic() + 60
        while "listening on" not in said and time.monotonic() < deadline:
            if select.select([proc.stderr], [], [], max(deadline - time.monotonic(), 0))[0]:
                line = proc.stderr.readline()
                if not line:  # the router ended already
                    break
                said += line
        assert "listening on" in said, said
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
        proc.wait()
    assert proc.returncode == 0, err
    assert "zenoh router closed" in err and "Traceback" not in err and out == ""
