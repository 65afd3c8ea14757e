"""The learning processes of a sweep (``ablate``, ``reproduce``) as one SLURM job array: a task per process, each
its own :class:`~tools.sweeps.jobs.Job` in a file, its outcome in another, collected into the same list the
local ``--jobs`` path returns::

    outcomes = SlurmArray(out_dir / "slurm", ArrayConfig(slurm=True)).learn(todo, progress)   # [(job, outcome), ...]
    # each task runs `ennc-ql slurm task FOLDER`: run_task(FOLDER, task_id)

``FOLDER`` (on a file system every node sees) holds ``tasks/<i>.toml`` (the job), ``results/<i>.json`` and
``results/<i>.npz`` (its outcome and policy), ``logs/task-<i>.log``, the array script and ``array.json`` (the
array submitted last). Submitting skips the tasks that already have a result and waits for an array still
queued, so the same command run again after an interruption submits only what is missing.
"""

from __future__ import annotations

import json
import logging
import shlex
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.experiments import Outcome
from algorithm.files import write_atomic
from algorithm.policy_file import load_policy, save_policy
from tools.cluster.children import log_tail
from tools.config import dump_config, load_config
from tools.slurm.sbatch import SBATCH_FIELD, SlurmError, slurm_command, submit
from tools.sweeps.jobs import Job, JobsBar

log = logging.getLogger(__name__)

ARRAY_SCRIPT = "array.sh"
SUBMITTED = "array.json"
POLL_S = 1.0
"""Seconds between looks at the queue and the results folder."""
RESULT_GRACE_S = 10.0
"""Seconds a task's result may take to appear once the array left the queue (a network file system's caches)."""


@dataclass(frozen=True, slots=True)
class ArrayConfig:
    slurm: bool = False
    """Run the learning processes as a SLURM job array (one task per variant x process) and wait for it; run the
    same command again after an interruption: only the tasks without a result are submitted."""
    sbatch: tuple[str, ...] = field(default=(), metadata=SBATCH_FIELD)
    """More sbatch options for every task, as one string: '--partition=cpu --time=1:00:00 --mem=4G'."""
    array_limit: int = 0
    """Tasks of the array running at once (sbatch --array=...%N; 0: as many as the cluster allows)."""

    def __post_init__(self) -> None:
        if self.array_limit < 0:
            raise ValueError(f"array_limit must be 0 (no limit) or more, got {self.array_limit}")


def _paths(folder: Path, i: int) -> tuple[Path, Path, Path]:
    """Task ``i``'s job file, outcome and policy."""
    return folder / "tasks" / f"{i}.toml", folder / "results" / f"{i}.json", folder / "results" / f"{i}.npz"


def write_tasks(todo: Sequence[Job], folder: Path) -> list[int]:
    """One job file per task; a task whose job changed loses its old result. The tasks without a result."""
    for sub in ("tasks", "results", "logs"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    missing = []
    for i, job in enumerate(todo):
        task, result, policy = _paths(folder, i)
        text = dump_config(job)
        if not task.exists() or task.read_text() != text:
            result.unlink(missing_ok=True)
            policy.unlink(missing_ok=True)
            task.write_text(text)
        if not result.exists():
            missing.append(i)
    return missing


def array_script(folder: Path, config: ArrayConfig) -> str:
    lines = [
        "#!/bin/bash",
        "# The learning processes of a sweep, one per array task, written by ennc-ql ablate/reproduce --slurm.",
        f"#SBATCH --job-name=ennc-ql-{folder.parent.name}",
        "#SBATCH --ntasks=1",
        "#SBATCH --cpus-per-task=1",  # each learning process runs torch on one thread
        f"#SBATCH --output={folder}/logs/task-%a.log",
        *(f"#SBATCH {option}" for option in config.sbatch),
        shlex.join(["exec", sys.executable, "-m", "ennc_ql.cli", "slurm", "task", str(folder)]),
    ]
    return "\n".join(lines) + "\n"


def run_task(folder: Path, task: int) -> Outcome:
    """An array task's side (``ennc-ql slurm task``): task ``task``'s learning process, its outcome written."""
    import torch  # here, in the task: as in a local worker, one thread per learning process

    torch.set_num_threads(1)
    job_file, result, policy_file = _paths(folder, task)
    job = load_config(Job, file=job_file)
    outcome = job.run(lambda stage: log.info("%s: %s", job.label, stage))
    if outcome.policy is not None:
        save_policy(outcome.policy, job.scenario, policy_file)
    figures = {
        "method": outcome.method,
        "seed": outcome.seed,
        "coverage_per_trial": [float(c) for c in outcome.coverage_per_trial],
        "states": outcome.states,
        "tuples": outcome.tuples,
        "seconds": outcome.seconds,
        "policy": outcome.policy is not None,
    }
    write_atomic(result, json.dumps(figures).encode())  # last: a result file is a finished task
    return outcome


def read_outcome(folder: Path, task: int) -> Outcome:
    _, result, policy_file = _paths(folder, task)
    figures = json.loads(result.read_text())
    return Outcome(
        method=figures["method"],
        seed=int(figures["seed"]),
        policy=load_policy(policy_file)[0] if figures["policy"] else None,
        coverage_per_trial=np.asarray(figures["coverage_per_trial"], dtype=np.float64),
        states=float(figures["states"]),
        tuples=int(figures["tuples"]),
        seconds=float(figures["seconds"]),
    )


def _compact(tasks: Sequence[int]) -> str:
    """Task ids as SLURM's --array list: 0-3,5,7-8."""
    runs: list[list[int]] = []
    for i in sorted(tasks):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    return ",".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def _queued(job_id: str) -> bool:
    """Whether any task of array ``job_id`` is still pending or running."""
    return bool(slurm_command(["squeue", "--noheader", f"--jobs={job_id}", "--format=%i"]).strip())


def submit_array(folder: Path, tasks: Sequence[int], config: ArrayConfig) -> str:
    """Submit ``tasks`` of the array in ``folder`` (or return the array of an earlier submission still queued)."""
    submitted = folder / SUBMITTED
    if submitted.exists():
        earlier: dict[str, Any] = json.loads(submitted.read_text())
        try:
            if _queued(earlier["job_id"]):
                log.info("array %s from an earlier submission is still queued: waiting for it", earlier["job_id"])
                return str(earlier["job_id"])
        except SlurmError:
            pass  # a job the scheduler no longer knows is not queued
    script = folder / ARRAY_SCRIPT
    script.write_text(array_script(folder, config))
    limit = f"%{config.array_limit}" if config.array_limit else ""
    job_id = submit(script, f"--array={_compact(tasks)}{limit}")
    submitted.write_text(json.dumps({"job_id": job_id, "tasks": list(tasks), "submitted": time.time()}))
    log.info("submitted %d learning processes as array job %s", len(tasks), job_id)
    return job_id


def learn_on_slurm(
    todo: Sequence[Job], folder: Path, config: ArrayConfig, progress: JobsBar
) -> list[tuple[Job, Outcome]]:
    """Every learning process of ``todo`` as a task of one job array, waited for; the outcomes, as
    :meth:`tools.sweeps.jobs.Backend.learn` returns them. Raises :class:`SlurmError` naming the tasks that ended
    without a result, with the end of their logs."""
    folder = folder.resolve()
    fresh = not folder.exists()
    missing = write_tasks(todo, folder)
    done = [i for i in range(len(todo)) if i not in missing]
    for i in done:
        progress.finished(f"{todo[i].label}: {read_outcome(folder, i).coverage_mean:.2f}% (an earlier result)")
    if missing:
        try:
            job_id = submit_array(folder, missing, config)
        except SlurmError as exc:
            if fresh:  # nothing was submitted from it: the files written for the array are taken back
                shutil.rmtree(folder, ignore_errors=True)
            raise SlurmError(f"{exc}; nothing was submitted") from None
        progress.running(f"{len(missing)} learning processes as SLURM array {job_id}")
        waiting = list(missing)
        while waiting:
            queued = _queued(job_id)
            for i in [i for i in waiting if _paths(folder, i)[1].exists()]:
                waiting.remove(i)
                progress.finished(f"{todo[i].label}: {read_outcome(folder, i).coverage_mean:.2f}%")
                progress.running(f"{len(waiting)} learning processes left in array {job_id}")
            if not queued:
                break
            time.sleep(POLL_S)
        # A result written on another node may take a moment to show on a network file system.
        deadline = time.monotonic() + RESULT_GRACE_S
        while any(not _paths(folder, i)[1].exists() for i in waiting) and time.monotonic() < deadline:
            time.sleep(POLL_S)
        failed = [i for i in waiting if not _paths(folder, i)[1].exists()]
        if failed:
            tails = "\n".join(
                f"task {i} ({todo[i].label}):\n{log_tail(folder / 'logs' / f'task-{i}.log', 5)}" for i in failed[:3]
            )
            raise SlurmError(
                f"array {job_id}: {len(failed)} of {len(missing)} tasks ended without a result (tasks "
                f"{_compact(failed)}; logs in {folder / 'logs'}); run the same command again to resubmit them. "
                f"The first:\n{tails}"
            )
    return [(job, read_outcome(folder, i)) for i, job in enumerate(todo)]


@dataclass(frozen=True, slots=True)
class SlurmArray:
    """A sweep's learning processes as one SLURM job array whose files are in ``folder``
    (a :class:`~tools.sweeps.jobs.Backend`)."""

    folder: Path
    config: ArrayConfig

    def learn(self, todo: Sequence[Job], progress: JobsBar) -> list[tuple[Job, Outcome]]:
        return learn_on_slurm(todo, self.folder, self.config, progress)
