"""``ennc-ql slurm``: training runs as SLURM batch jobs, and the two commands that jobs run.

    ennc-ql slurm train --actors 4 --nodes 3 --duration 3600 --run-id exp1 [--submit]   # runs/exp1/job.sh
    sbatch runs/exp1/job.sh                                                              # if not --submit
    ennc-ql slurm run runs/exp1        # what job.sh runs, inside the allocation
    ennc-ql slurm task FOLDER          # what an array task of ablate/reproduce --slurm runs

``train`` takes ``up``'s run configuration (``--actors``, ``--duration``, ``--learner-*``, ``--actor-*``, or
``--config up.toml``) and the job's (``--nodes``, ``--partition``, ``--time-limit``, ``--account``, ``--sbatch``,
``--no-secure``).
"""

from __future__ import annotations

import argparse
import os
import shutil
import time
from pathlib import Path
from typing import Any

from ennc_ql.command import configure, emit, fail, refuse_run, writable_dir
from ennc_ql.parser import CommandHelp, add_command, add_commands, say
from ennc_ql.report import emit_run_report
from protocol import check_id
from tools.cluster import SET_BY_UP, UP_PRESETS, LaunchError, RunSummary, SlurmFigures, UpConfig
from tools.config import ConfigError, add_config_flags, file_path, folder, load_config
from tools.slurm.array import run_task
from tools.slurm.job import JOB_SCRIPT, SlurmJob, run_training_job, write_training_job
from tools.slurm.sbatch import SlurmError, submit
from tools.system import stop_on_signals

SLURM = CommandHelp(
    "slurm",
    "training runs as SLURM batch jobs (sweeps: ablate/reproduce --slurm)",
    "Trains on a SLURM allocation: slurm train writes a run folder and its job script (router and learner on the "
    "first node, actors round-robin on the others as job steps), and slurm run is what the script runs inside the "
    "allocation. Sweeps (ablate and reproduce --slurm) run their learning processes as one job array of slurm task. "
    "See each subcommand's help, and docs/guide/slurm.md.",
    (
        ("ennc-ql slurm train --actors 4 --nodes 3 --submit", "a training job on 3 nodes"),
        ("ennc-ql ablate --slurm ennc-ql-local --set budget.phase2.alpha=0.1,0.3", "a sweep as one job array"),
    ),
    "under a second to write or submit; the job runs --duration plus about a minute",
)

TRAIN = CommandHelp(
    "train",
    "write a training run's folder and job script; --submit to sbatch it",
    "Writes runs/<id>/: up.toml (the run's configuration, as ennc-ql up takes it) and job.sh, a batch script whose "
    "router and learner run on the first node of the allocation and whose actors run round-robin on the others, as "
    "srun job steps, joined by the nodes' addresses with mutual TLS unless --no-secure. The script asks SLURM to "
    "requeue it; a requeued job continues from the run's checkpoint. --submit submits it with sbatch; otherwise the "
    "line printed says how. It refuses a folder that holds a run already.",
    (
        ("ennc-ql slurm train --actors 4 --nodes 3 --duration 3600 --submit", "one hour on 3 nodes, submitted"),
        ("ennc-ql slurm train --config runs/<id>/up.toml --run-id again", "a local run's configuration, as a job"),
        ("ennc-ql slurm train --partition gpu --sbatch=--mem=8G", "the job's own sbatch options"),
    ),
    "under a second (sbatch with --submit); the job itself: --duration plus about a minute",
)

RUN = CommandHelp(
    "run",
    "a training job's own side, run by its job.sh inside the allocation",
    "Runs the training of a folder slurm train wrote, inside its SLURM allocation: the router and learner here, "
    "each actor as a job step on its node, supervised as ennc-ql up supervises them (a learner that dies is "
    "restarted from its checkpoint), then the report in the run folder. Outside a job it says so and stops.",
    (
        ("ennc-ql slurm run runs/exp1", "what runs/exp1/job.sh runs"),
        ("ennc-ql slurm run runs/exp1 --json", "the report as one JSON object"),
    ),
    "the run's --duration plus start-up and the final evaluation (about a minute)",
)

TASK = CommandHelp(
    "task",
    "one learning process of a sweep's job array (ablate/reproduce --slurm)",
    "Runs one task of a sweep's job array: the variant and seed that the task number names in the sweep's slurm "
    "folder, whose outcome it writes there for ablate or reproduce to collect. The task number comes from "
    "SLURM_ARRAY_TASK_ID, or --task to run one by hand.",
    (
        ("ennc-ql slurm task runs/ablate-ennc-ql-local/slurm", "the array task SLURM_ARRAY_TASK_ID names"),
        ("ennc-ql slurm task runs/ablate-ennc-ql-local/slurm --task 3", "task 3 by hand, e.g. to debug it"),
    ),
    "one learning process: about 20 s with --quick, about 3 min at the full budget (2 cores)",
)


def add_slurm_parser(sub: Any) -> None:
    p = add_command(sub, SLURM)
    inner = add_commands(p, dest="slurm_command")

    train = add_command(inner, TRAIN)
    train.add_argument(
        "--config",
        type=file_path,
        metavar="FILE",
        help="TOML file of the run's configuration, e.g. a run's up.toml (default: none)",
    )
    train.add_argument("--runs", type=folder, default=Path("runs"), help="parent folder of the run folder")
    train.add_argument("--run-id", help="run folder name (default: a timestamp)")
    train.add_argument("--submit", action="store_true", help="submit the job script with sbatch")
    train.add_argument("--json", action="store_true", help="print the result as one JSON object")
    add_config_flags(
        train.add_argument_group("run configuration (tools.cluster.UpConfig)"),
        UpConfig,
        exclude=SET_BY_UP,
        defaults=UP_PRESETS,
    )
    add_config_flags(train.add_argument_group("the job (tools.slurm.job.SlurmJob)"), SlurmJob)
    train.set_defaults(func=cmd_train)

    run = add_command(inner, RUN)
    run.add_argument("run_dir", type=folder, metavar="RUN_DIR", help="the run folder `slurm train` wrote")
    run.add_argument("--json", action="store_true", help="print the report as one JSON object")
    run.set_defaults(func=cmd_run)

    task = add_command(inner, TASK)
    task.add_argument("folder", type=folder, metavar="FOLDER", help="the sweep's slurm folder")
    task.add_argument("--task", type=int, help="the task (default: $SLURM_ARRAY_TASK_ID)")
    task.set_defaults(func=cmd_task)


def cmd_train(args: argparse.Namespace) -> int:
    config: UpConfig = configure(UpConfig, args, "slurm train", defaults=UP_PRESETS)
    try:
        job = load_config(SlurmJob, args=args)  # flags only: --config is the run's configuration
        job.check_actors(config.actors)
    except (ConfigError, ValueError) as exc:
        fail("slurm train", str(exc))
    run_id = args.run_id if args.run_id is not None else time.strftime("%Y%m%d-%H%M%S")
    try:
        check_id(run_id, "--run-id")
    except ValueError as exc:
        fail("slurm train", str(exc))
    folder = args.runs / run_id
    # A job script alone is a run too: written, perhaps submitted, not started yet.
    job_script = folder / JOB_SCRIPT
    resume = f"sbatch {job_script}" if job_script.is_file() else None  # another command's run has no job script
    refuse_run(folder, "slurm train", f"--run-id {run_id}: {folder}", resume, another="give a fresh --run-id")
    before = set(folder.iterdir()) if folder.is_dir() else None
    run_dir = writable_dir(folder, "slurm train", "--runs")
    script = write_training_job(config, job, run_dir)
    result: dict[str, Any] = {"run_dir": str(script.parent), "job_script": str(script), "job_id": None}
    if args.submit:
        try:
            result["job_id"] = submit(script)
        except SlurmError as exc:
            # Nothing was submitted: what this command wrote goes, so the same --run-id can be tried again.
            _remove_new(run_dir, before)
            fail("slurm train", f"{exc}; nothing was submitted")
    nodes = job.node_count(config.actors)
    line = f"{script}: {config.actors} actors on {nodes} node(s), {config.duration:g} s of training; "
    line += f"submitted as job {result['job_id']}" if result["job_id"] else f"submit it with: sbatch {script}"
    emit(result, args.json, line)
    return 0


def _remove_new(folder: Path, before: set[Path] | None) -> None:
    """Remove ``folder`` where it did not exist (``before`` None), else what it holds that was not in ``before``."""
    if before is None:
        shutil.rmtree(folder, ignore_errors=True)
        return
    for path in set(folder.iterdir()) - before:
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def cmd_run(args: argparse.Namespace) -> int:
    run_dir = args.run_dir.resolve()
    if not (run_dir / JOB_SCRIPT).exists():
        fail("slurm run", f"{run_dir} is not a run folder written by `ennc-ql slurm train` (no {JOB_SCRIPT})")
    started = time.monotonic()
    try:
        done = run_training_job(run_dir, stop_on_signals())
    except (SlurmError, LaunchError, ConfigError) as exc:
        fail("slurm run", str(exc))
    alloc = done.allocation
    slurm = SlurmFigures(alloc.job_id, alloc.restarts, tuple(alloc.nodes), dict(done.placement.node_of))
    wall_seconds = time.monotonic() - started
    command = f"sbatch {run_dir / JOB_SCRIPT}"
    summary = RunSummary(
        run_dir, command, done.config, done.job.secure, wall_seconds, done.recording, run=done.run, slurm=slurm
    )
    emit_run_report(done.report, summary, args.json)
    return 0


def cmd_task(args: argparse.Namespace) -> int:
    task = args.task if args.task is not None else os.environ.get("SLURM_ARRAY_TASK_ID")
    if task is None:
        fail("slurm task", "no --task and no SLURM_ARRAY_TASK_ID: this runs inside an array job")
    if not str(task).isdigit():
        source = "--task" if args.task is not None else "SLURM_ARRAY_TASK_ID"
        fail("slurm task", f"{source}={task!r}: expected a task number (0 or more), as SLURM sets it in an array job")
    try:
        outcome = run_task(args.folder.resolve(), int(task))
    except (ConfigError, OSError) as exc:
        fail("slurm task", f"task {task} of {args.folder}: {exc}")
    say(f"task {task}: {outcome.method}[{outcome.seed}] {outcome.coverage_mean:.2f}% in {outcome.seconds:.0f} s")
    return 0
