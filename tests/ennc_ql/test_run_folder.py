"""A run folder is the user's data: every command that writes a run folder (or a recording into one) refuses a
folder holding a finished or interrupted run, unless it resumes that run, with one line naming how to continue it,
and leaves every file of the run byte-identical. The commands run as the console script does, in forks of one
process that imported the command line once (:mod:`tests.ennc_ql._forkserver`, as the error-contract rows)."""

from __future__ import annotations

import hashlib
import json
import os
import stat
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from tests.ennc_ql._forkserver import ForkServer
from tests.ennc_ql.test_bad_input import PRELOAD, Runner, run_forked
from tools.cluster import UP_PRESETS, UpConfig, child_configs, write_configs
from tools.config import load_config

ENNC_QL = Path(__import__("sys").executable).with_name("ennc-ql")


@pytest.fixture(scope="module")
def forked() -> Iterator[Runner]:
    from importlib.metadata import entry_points

    [script] = entry_points(group="console_scripts", name="ennc-ql")
    server = ForkServer(ENNC_QL, script.value, PRELOAD)
    yield lambda argv, cwd, env=None: run_forked(server, argv, cwd, env)
    server.close()
    assert server.proc.returncode == 0 and server.stderr() == "", server.stderr()


def finished_run(folder: Path) -> None:
    """What ``up`` leaves in ``runs/<id>`` once it ended: its configurations, the learner's checkpoint (a whole
    10 s trained), report, policy, recording and logs. The files' content is never read by a refusal."""
    config = load_config(UpConfig, defaults={**UP_PRESETS, "duration": 10.0})
    folder.mkdir(parents=True)
    write_configs(config, *child_configs(config), folder)
    meta = {"elapsed": 10.0, "config": {"formulation": config.formulation}}
    np.savez(folder / "checkpoint.npz", meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), big=np.ones(5000))
    (folder / "report.json").write_text(json.dumps({"final_coverage_mean": 78.5}))
    (folder / "report.md").write_text("# run finished\n")
    np.savez(folder / "policy.npz", tables=np.arange(12.0))
    (folder / "recording.rrd").write_bytes(os.urandom(4096))
    (folder / "learner.log").write_text("learner: final policy version 9\n")


def digest(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (names relative to it) with its content's hash and its modification time."""
    return {
        str(p.relative_to(folder)): f"{hashlib.sha256(p.read_bytes()).hexdigest()} {p.stat().st_mtime_ns}"
        for p in sorted(folder.rglob("*"))
        if stat.S_ISREG(p.stat().st_mode)
    }


ROWS: list[tuple[list[str], tuple[str, ...]]] = [
    (["up", "--run-id", "done"], ("--run-id done: runs/done holds a run already", "ennc-ql up --resume runs/done")),
    (["up", "--serial", "--run-id", "done"], ("holds a run already", "ennc-ql up --resume runs/done")),
    (["up", "--resume", "runs/done"], ("the run trained its whole 10 s already",)),
    (
        ["learner", "--run-dir", "runs/done"],
        ("--run-dir runs/done holds a run already", "--resume", "another --run-dir"),
    ),
    (["learner", "--run-dir", "runs/new", "--rerun", "save", "runs/done/recording.rrd"], ("its folder holds a run",)),
    (["actor", "--rerun", "save", "runs/done/recording.rrd"], ("--rerun save runs/done/recording.rrd: its folder",)),
    (["eval", "--rerun", "save", "runs/done/recording.rrd"], ("holds a run already", "give another folder")),
    # up's run has no job script to submit again: a fresh --run-id is the one way on.
    (["slurm", "train", "--runs", "runs", "--run-id", "done"], ("holds a run already", "overwrite: give a fresh")),
    (["slurm", "train", "--runs", "runs", "--run-id", "queued"], ("(job.sh)", "sbatch runs/queued/job.sh")),
    (["reproduce", "--quick", "--out", "runs/done"], ("--out runs/done holds a training run", "give another --out")),
    (["reproduce", "--quick", "--force", "--out", "runs/done"], ("holds a training run (checkpoint.npz",)),
    (["ablate", "fqi-mlp", "--force", "--out", "runs/done"], ("holds a training run", "give another --out")),
]


@pytest.mark.parametrize(("argv", "words"), ROWS, ids=[" ".join(argv) for argv, _ in ROWS])
def test_a_finished_runs_folder_is_refused_and_left_byte_identical(
    argv: list[str], words: tuple[str, ...], tmp_path: Path, forked: Runner
) -> None:
    finished_run(tmp_path / "runs" / "done")
    (tmp_path / "runs" / "queued").mkdir()
    (tmp_path / "runs" / "queued" / "job.sh").write_text("#!/bin/bash\n")
    before = digest(tmp_path)
    result = forked(argv, tmp_path, None)
    assert result.returncode == 2, result.stderr
    [line] = result.stderr.splitlines()
    assert line.startswith("ennc-ql ") and ": error: " in line
    for word in words:
        assert word in line, line
    assert digest(tmp_path) == before
    assert not (tmp_path / "runs" / "new").exists()


def test_a_learner_resuming_its_run_folder_is_not_refused(tmp_path: Path, forked: Runner) -> None:
    """The refusal is for a fresh start only: ``--resume`` passes it (and then fails on this fake checkpoint's
    missing arrays, one line naming the checkpoint, the folder left as it was)."""
    finished_run(tmp_path / "runs" / "done")
    before = digest(tmp_path)
    result = forked(["learner", "--run-dir", "runs/done", "--resume", "--listen", "tcp/127.0.0.1:0"], tmp_path, None)
    assert result.returncode == 2, result.stderr
    [line] = result.stderr.splitlines()
    assert "holds a run already" not in line and "is not a usable checkpoint" in line, line
    assert digest(tmp_path) == before


def test_a_failing_sbatch_is_one_line_and_leaves_no_run_folder(tmp_path: Path) -> None:
    """``slurm train --submit`` whose sbatch fails: exit 2, one line carrying sbatch's own words, and the folder it
    made is gone, so the same --run-id can be submitted again."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    sbatch = bin_dir / "sbatch"
    sbatch.write_text(
        "#!/bin/sh\necho 'sbatch: error: Batch job submission failed:' >&2\necho '  Invalid account' >&2\n"
        "echo 'sbatch: error: line three' >&2\necho '' >&2\necho 'line four' >&2\nexit 1\n"
    )
    sbatch.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "COLUMNS": "120"}
    argv = [str(ENNC_QL), "slurm", "train", "--runs", "runs", "--run-id", "x", "--submit"]
    done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=90)
    assert done.returncode == 2, done.stderr
    [line] = done.stderr.splitlines()
    assert line.startswith("ennc-ql slurm train: error: sbatch --parsable")
    assert "Batch job submission failed:; Invalid account; sbatch: error: line three; line four" in line
    assert line.endswith("nothing was submitted")
    assert list((tmp_path / "runs").iterdir()) == []


@pytest.mark.parametrize(
    "argv",
    [
        ["ablate", "ennc-ql-local", "--slurm", "--quick", "--processes", "1", "--out", "sweep"],
        ["reproduce", "--slurm", "--quick", "--methods", "ennc-ql-local", "--out", "sweep"],
    ],
    ids=["ablate", "reproduce"],
)
def test_a_sweep_whose_sbatch_fails_takes_back_what_it_wrote(tmp_path: Path, argv: list[str]) -> None:
    """A sweep on SLURM whose first submission fails: one line, exit 2, and no output folder left (nothing was
    submitted, so nothing there could be resubmitted)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    sbatch = bin_dir / "sbatch"
    sbatch.write_text("#!/bin/sh\necho 'sbatch: error: Batch job submission failed: Invalid account' >&2\nexit 1\n")
    sbatch.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "COLUMNS": "120"}
    done = subprocess.run([str(ENNC_QL), *argv], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    [line] = [line for line in done.stderr.splitlines() if "error:" in line]
    assert f"ennc-ql {argv[0]}: error: sbatch --parsable" in line and "Invalid account" in line, line
    assert line.endswith("nothing was submitted"), line
    assert not (tmp_path / "sweep").exists()
