"""On a real SLURM (three emulated nodes started in a temporary folder, :mod:`tests.e2e.slurm`):

- a training job submitted as the README says (``ennc-ql slurm train ... --submit``), one actor task SIGKILLed
  mid-run and the job requeued: the actor comes back, the requeued job resumes from the checkpoint, and the final
  report shows every tuple stored exactly once, versions strictly increasing across the requeue, the restart;
- a tiny ``ablate`` sweep as a job array gives the same results.md and byte-identical policy files as the local
  ``--jobs`` path on the same variants, and run again submits nothing;

and every daemon, job step and task is gone afterwards. Without SLURM's packages the tests skip saying why (CI sets
``ENNC_QL_REQUIRE_SLURM=1``: there they fail instead).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
from pathlib import Path

import numpy as np
import psutil
import pytest

from learner.checkpoint import VersionMark
from tests.e2e import ACTOR_PACE, ennc_ql
from tests.e2e import slurm as local_slurm
from tests.e2e.cluster import checkpoint_version
from tests.e2e.slurm import LocalSlurm, require_slurm

pytestmark = pytest.mark.slow

# up's flags for a run of seconds on busy cores (as tests/e2e/test_up_supervision.py).
SMALL_RUN = [
    "--actors=2",
    "--actor-arenas=16",
    f"--actor-max-tuples-per-s={ACTOR_PACE}",
    "--actor-batch-size=1024",
    "--learner-min-tuples=5000",
    "--learner-phase1-max-patterns=300",
    "--learner-phase1-n-cycles=10",
    "--learner-eval-interval=1000",
    "--learner-eval-trials=1",
    "--learner-final-eval-trials=2",
    "--learner-checkpoint-interval=1",
    "--learner-phase1-max-iterations=1",
    # The run's end chooses the saved policy's law margin: with the default 300 validation trials x 7 margins, past
    # the test cluster's KillWait of 30 s on loaded cores.
    "--learner-margin-trials=2",
    "--learner-phase1-seed-prototypes=32",  # the default 512 seeds take the first fit 10-16 s on loaded cores
    # A requeue stops the router with the rest: the actors' last acknowledgements cannot come, so they stop soon.
    "--actor-flush-timeout=3",
]
TINY_BUDGET = [
    f"--set=budget.{key}"
    for key in (
        "arenas=16",
        "explore_trials=1",
        "phase2_trials=2",
        "phase1.n_cycles=10",
        "phase1.max_patterns=300",
        "test_trials=1",
        "test_steps=200",
    )
]


@pytest.fixture
def slurm(tmp_path: Path) -> LocalSlurm:
    require_slurm()
    return LocalSlurm(tmp_path / "slurm")


def task_pid(config: Path) -> int:
    """The pid of the job step's task started with ``config`` (its python process, not srun)."""
    for proc in psutil.process_iter(["pid", "cmdline"]):
        cmdline = proc.info["cmdline"] or []
        if str(config) in cmdline and "srun" not in cmdline[0]:
            return int(proc.info["pid"])
    raise AssertionError(f"no task runs {config}")


def checkpoint_by_actor(run_dir: Path) -> dict[str, int]:
    """The tuples of each actor the run folder's checkpoint holds."""
    with np.load(run_dir / "checkpoint.npz") as data:
        by_actor: dict[str, int] = json.loads(data["intake_meta"].tobytes())["by_actor"]
    return by_actor


def test_a_training_job_survives_a_killed_actor_task_and_a_requeue(slurm: LocalSlurm, tmp_path: Path) -> None:
    run_dir = tmp_path / "runs" / "train"
    with slurm:
        out = slurm.run(
            *ennc_ql("slurm", "train", "--nodes=3", "--duration=24", *SMALL_RUN, f"--runs={tmp_path / 'runs'}"),
            "--run-id=train",
            "--submit",
            "--json",
        )
        job_id = json.loads(out)["job_id"]
        log = run_dir / f"slurm-{job_id}.out"
        # One actor task SIGKILLed mid-run: the job's supervision starts it again as a new job step.
        slurm.wait_for(lambda: "incarnation" in text(run_dir / "actor-1.log"), 120, "actor-1 to run")
        os.kill(task_pid(run_dir / "actor-1.toml"), signal.SIGKILL)
        slurm.wait_for(lambda: text(run_dir / "actor-1.log").count("incarnation") == 2, 60, "actor-1 back")
        assert "actor-1 exited with status 137; restarting in 1 s" in text(log)
        # Requeued once a policy is checkpointed: every task stops, the job waits in the queue, then runs again.
        slurm.wait_for(lambda: checkpoint_version(run_dir) >= 1, 120, "a checkpointed policy")
        slurm.run("scontrol", "requeue", job_id)
        slurm.wait_for(lambda: slurm.job(job_id).get("JobState") == "PENDING", 120, "the job back in the queue")
        first = json.loads((run_dir / "report.json").read_text())
        held, published = checkpoint_by_actor(run_dir), VersionMark(run_dir).load()
        slurm.run("scontrol", "update", f"jobid={job_id}", "StartTime=now")  # SLURM delays a requeued job 2 min
        assert slurm.wait_job(job_id, timeout=300) == "COMPLETED", text(log)[-3000:]
        report = json.loads((run_dir / "report.json").read_text())
    assert slurm.leftovers() == []

    # Router and learner on the first node, one actor on each other node; the first run restarted actor-1 once.
    assert report["slurm"]["placement"] == {"router": "n1", "learner": "n1", "actor-0": "n2", "actor-1": "n3"}
    assert first["actor_restarts"] == {"actor-1": 1} and first["actors_sent"]["actor-1"]["incarnations"] == 2
    # The requeued job resumed from the checkpoint, its first broadcast above every version sent before.
    assert report["slurm"]["requeued"] == 1
    [resume] = report["resumes"]
    started = [int(v) for v in re.findall(r"started \(policy version (\d+)\)", text(run_dir / "learner.log"))]
    assert started == [0, resume["policy_version"]] and resume["policy_version"] > published >= 1
    assert report["policy_versions"]["increasing"] and report["policy_versions"]["first"] > published
    assert report["policy_version"] == report["policy_versions"]["last"]
    # Exactly once: what the requeued run's actors sent (all acknowledged) on top of what the checkpoint held.
    assert report["gaps"] == 0
    for actor in ("actor-0", "actor-1"):
        sent = report["actors_sent"][actor]
        assert sent["incarnations"] == sent["reported"] == 1 and sent["tuples_sent"] == sent["tuples_acked"] > 0
        assert report["tuples_by_actor"][actor] == held[actor] + sent["tuples_sent"] and held[actor] > 0
    # The usual report, and the slurm output of both runs of the job.
    assert report["final_coverage_mean"] is not None and (run_dir / "report.md").exists()
    assert report["first_policy_s"] is not None and report["recording"]["recording_ids"] == ["train"]
    assert text(log).count("training ends: the actors stop") == 1


def test_a_sweep_as_a_job_array_gives_the_local_results(slurm: LocalSlurm, tmp_path: Path) -> None:
    sweep = ["ablate", "ennc-ql-collab-option2", "--set=budget.phase2.alpha=0.05,0.2", *TINY_BUDGET, "--processes=1"]
    argv = ennc_ql(*sweep, "--jobs=2", f"--out={tmp_path / 'local'}", "--json")
    local = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # meanwhile
    array = tmp_path / "array"
    try:
        with slurm:
            first = slurm.run(*ennc_ql(*sweep, "--slurm", f"--out={array}", "--json"))
            submitted = json.loads((array / "slurm" / "array.json").read_text())
            # Its results are there now: another run replaces them only when asked to (--force).
            again = slurm.run(*ennc_ql(*sweep, "--slurm", f"--out={array}", "--force", "--json"))
        local_out, local_err = local.communicate(timeout=300)
    finally:
        if local.poll() is None:
            local.kill()
            local.wait()
    assert local.returncode == 0, local_err[-3000:]
    assert slurm.leftovers() == []

    # One task per variant x process, the same learning processes as the local path: the same table and the same
    # policy files, byte for byte.
    assert submitted["tasks"] == [0, 1]
    assert (array / "results.md").read_text() == (tmp_path / "local" / "results.md").read_text()
    for name in ("v1-0.npz", "v2-0.npz"):
        assert (array / "policies" / name).read_bytes() == (tmp_path / "local" / "policies" / name).read_bytes()
    rows = [json.loads(first)["variants"], json.loads(local_out)["variants"]]
    assert [r["coverage_per_run"] for r in rows[0]] == [r["coverage_per_run"] for r in rows[1]]
    assert (array / "ablation.png").exists()
    # Run again: every task has its result, nothing is submitted, the report is the same.
    assert json.loads((array / "slurm" / "array.json").read_text()) == submitted
    assert json.loads(again)["variants"] == json.loads(first)["variants"]


def text(path: Path) -> str:
    return path.read_text(errors="replace") if path.exists() else ""


def test_without_slurm_these_tests_skip_saying_why_but_fail_where_they_are_required(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("PATH", "/nonexistent")
    monkeypatch.setattr(local_slurm, "SBIN", "/nonexistent")
    monkeypatch.delenv(local_slurm.REQUIRE, raising=False)
    with pytest.raises(pytest.skip.Exception, match="no local SLURM: mungekey, munged, slurmctld, slurmd, sbatch"):
        require_slurm()
    monkeypatch.setenv(local_slurm.REQUIRE, "1")  # as .ci/run sets it
    with pytest.raises(pytest.fail.Exception, match="but ENNC_QL_REQUIRE_SLURM=1 requires the SLURM tests to run"):
        require_slurm()
