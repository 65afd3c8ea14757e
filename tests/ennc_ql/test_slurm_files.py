"""``ennc-ql slurm`` without a cluster: the run folder and job script ``slurm train`` writes, where a job puts each
process, a sweep's task files and outcomes, and the one-line errors. (On a real SLURM: tests/e2e/test_slurm.py.)"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from algorithm.experiments import Budget
from algorithm.phase1 import Phase1Config
from ennc_ql.cli import main
from sim import Formulation, scenario
from tools.cluster import UpConfig
from tools.config import load_config
from tools.slurm.allocation import Allocation, SlurmPlacement
from tools.slurm.array import _compact, read_outcome, run_task, write_tasks
from tools.slurm.job import SlurmJob
from tools.slurm.sbatch import SlurmError
from tools.sweeps.jobs import Job


def test_slurm_train_writes_a_run_folder_and_a_job_script(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    argv = ["slurm", "train", "--actors=4", "--nodes=3", "--duration=600", "--actor-arenas=200", "--time-limit=2:00:00"]
    argv += ["--sbatch", "--exclusive --mem=8G --gres=gpu:1,shard:2", f"--runs={tmp_path}", "--run-id=exp1", "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    run_dir = tmp_path / "exp1"
    assert out == {"run_dir": str(run_dir), "job_script": str(run_dir / "job.sh"), "job_id": None}
    script = (run_dir / "job.sh").read_text()
    directives = [line.removeprefix("#SBATCH ") for line in script.splitlines() if line.startswith("#SBATCH")]
    assert directives == [
        "--job-name=ennc-ql-exp1",
        "--nodes=3",
        "--ntasks-per-node=2",  # router and learner on the first node, two actors on each of the others
        "--requeue",
        "--open-mode=append",
        f"--output={run_dir}/slurm-%j.out",
        "--time=2:00:00",
        "--exclusive",
        "--mem=8G",
        "--gres=gpu:1,shard:2",
    ]
    assert script.splitlines()[-1].endswith(f"-m ennc_ql.cli slurm run {run_dir}")
    # The run's configuration as up writes it, and the job's own, read back as the job reads them.
    config = load_config(UpConfig, file=run_dir / "up.toml")
    assert (config.actors, config.duration, config.actor.arenas) == (4, 600.0, 200)
    assert sorted(p.name for p in run_dir.glob("actor-*.toml")) == [f"actor-{i}.toml" for i in range(4)]
    job = load_config(SlurmJob, file=run_dir / "slurm.toml")
    assert job == SlurmJob(nodes=3, time_limit="2:00:00", sbatch=("--exclusive", "--mem=8G", "--gres=gpu:1,shard:2"))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["slurm", "train", "--nodes=-1"], "nodes must be 0 (one per actor, plus one) or more, got -1"),
        (["slurm", "train", "--sbatch", "exclusive"], "expected sbatch options such as --mem=8G, got 'exclusive'"),
        (["slurm", "train", "--actors=0"], "actors must be at least 1"),
        (["slurm", "run", "."], "is not a run folder written by `ennc-ql slurm train` (no job.sh)"),
        (["ablate", "ennc-ql-local", "--array-limit=-2"], "array_limit must be 0 (no limit) or more, got -2"),
    ],
)
def test_bad_slurm_input_is_one_line(capsys: pytest.CaptureFixture[str], argv: list[str], message: str) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) <= 2 and lines[1:] == [line for line in lines[1:] if line.startswith("usage: ")]
    assert lines[0].startswith(f"ennc-ql {argv[0]}") and ": error: " in lines[0] and message in lines[0]


def test_slurm_train_never_writes_over_a_run(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["slurm", "train", f"--runs={tmp_path}", "--run-id=r"]) == 0
    (tmp_path / "r" / "checkpoint.npz").write_bytes(b"a run's checkpoint")
    with pytest.raises(SystemExit) as exit_info:
        main(["slurm", "train", f"--runs={tmp_path}", "--run-id=r", "--actors=5"])
    assert exit_info.value.code == 2
    assert (
        capsys.readouterr()
        .err.strip()
        .endswith(
            "holds a run already (checkpoint.npz, job.sh), which this would overwrite: continue it with sbatch "
            f"{tmp_path / 'r' / 'job.sh'}, or give a fresh --run-id"
        )
    )
    assert load_config(UpConfig, file=tmp_path / "r" / "up.toml").actors == 2  # untouched


def test_slurm_run_outside_a_job_says_so(tmp_path: Path) -> None:
    assert main(["slurm", "train", f"--runs={tmp_path}", "--run-id=r"]) == 0
    env = {"PATH": "/usr/bin:/bin"}  # no SLURM_* variables
    done = subprocess.run(
        [sys.executable, "-m", "ennc_ql.cli", "slurm", "run", str(tmp_path / "r")],
        env=env,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2
    assert done.stderr.strip().endswith(
        "not inside a SLURM job (SLURM_JOB_ID, SLURM_JOB_NODELIST, SLURMD_NODENAME not set): submit the job script "
        "with sbatch"
    )


def test_the_router_and_learner_stay_on_the_batch_node_and_actors_go_round_robin() -> None:
    alloc = Allocation("7", ("n1", "n2", "n3"), "n1", {"n1": "10.0.0.1", "n2": "10.0.0.2", "n3": "10.0.0.3"})
    placement = SlurmPlacement.of(alloc, [f"actor-{i}" for i in range(3)])
    assert dict(placement.node_of) == {
        "router": "n1",
        "learner": "n1",
        "actor-0": "n2",
        "actor-1": "n3",
        "actor-2": "n2",
    }
    assert placement.host == "10.0.0.1" and placement.stop_signal == signal.SIGUSR1
    command = placement.command("actor-1", ["python", "-m", "ennc_ql.cli", "actor"])
    assert command[:6] == ["srun", "--overlap", "--nodes=1", "--ntasks=1", "--nodelist=n3", "--job-name=actor-1"]
    alone = SlurmPlacement.of(Allocation("8", ("n1",), "n1", {"n1": "127.0.0.1"}), ["actor-0"])
    assert set(alone.node_of.values()) == {"n1"}


def test_allocation_outside_a_job_is_an_error() -> None:
    with pytest.raises(SlurmError, match="SLURMD_NODENAME not set"):
        Allocation.from_environment({"SLURM_JOB_ID": "1", "SLURM_JOB_NODELIST": "n1"})


def test_a_sweep_task_runs_its_job_and_its_outcome_reads_back_whole(tmp_path: Path) -> None:
    phase1 = Phase1Config(n_cycles=5, max_patterns=200)
    tiny = Budget(arenas=8, explore_trials=1, phase2_trials=1, phase1=phase1, test_trials=1, test_steps=50)
    # Task 1 learns on another formulation than the method's: the job file carries it by name.
    other = Formulation.of("local2d", "difference-decision", "relative", act_every=2, trial_rules="search-on")
    jobs = [Job("ennc-ql-local", tiny, 0, scenario()), Job("ennc-ql-local", tiny, 1, scenario(), formulation=other)]
    assert write_tasks(jobs, tmp_path) == [0, 1]
    assert "local2d/difference-decision/relative/2/search-on" in (tmp_path / "tasks" / "1.toml").read_text()
    outcome = run_task(tmp_path, 1)
    assert outcome.policy is not None and outcome.policy.formulation == other
    assert write_tasks(jobs, tmp_path) == [0]  # task 1 has its result now
    back = read_outcome(tmp_path, 1)
    assert (back.method, back.seed, back.tuples, back.states) == (outcome.method, 1, outcome.tuples, outcome.states)
    np.testing.assert_array_equal(back.coverage_per_trial, outcome.coverage_per_trial)
    assert back.policy is not None and outcome.policy is not None
    np.testing.assert_array_equal(back.policy.discretization.prototypes, outcome.policy.discretization.prototypes)
    np.testing.assert_array_equal(back.policy.tables, outcome.policy.tables)
    # Another sweep in the same folder: a task whose job changed loses its result, and is to be run again.
    assert write_tasks([jobs[0], Job("ennc-ql-local", tiny, 5, scenario())], tmp_path) == [0, 1]


def test_array_task_lists_are_compact() -> None:
    assert _compact([7, 0, 1, 2, 5, 8]) == "0-2,5,7-8"
    assert _compact([3]) == "3"
