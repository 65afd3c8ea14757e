"""A training run as a SLURM batch job: the run folder with every process's configuration and a job script, and the
job's own side, which runs the router, the learner and the actors as job steps of its allocation::

    job = SlurmJob(nodes=3)
    script = write_training_job(config, job, run_dir)      # run_dir/job.sh, up.toml, slurm.toml, ...
    job_id = submit(script)                                # tools.slurm.sbatch: sbatch --parsable job.sh
    # inside the allocation, job.sh runs `ennc-ql slurm run RUN_DIR`:
    run_training_job(run_dir, stop)                        # the report, as ``up`` writes it

The job is secure by default (``secure init`` into ``RUN/secure`` on a shared file system, each process given only
its own configuration, which names only its own key and certificate), requeueable (``#SBATCH --requeue``: a
requeued job resumes from the run folder's checkpoint, its output appended to ``slurm-<job id>.out``), and
supervises its steps as ``up`` supervises its children: an actor, the router or the learner that dies is started
again (the learner with ``--resume auto``).
"""

from __future__ import annotations

import math
import re
import shlex
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path

from learner.report import LearnerReport
from monitor import Sink, paths
from tools.cluster import (
    LaunchError,
    Monitoring,
    ProcessRun,
    RecordingFigures,
    UpConfig,
    child_configs,
    run_to_report,
    write_configs,
)
from tools.config import dump_config, load_config
from tools.slurm.allocation import Allocation, SlurmPlacement
from tools.slurm.sbatch import SBATCH_FIELD

JOB_SCRIPT = "job.sh"
JOB_CONFIG = "slurm.toml"


@dataclass(frozen=True, slots=True)
class SlurmJob:
    nodes: int = 0
    """Nodes of the job: the first runs the router and the learner, the others the actors, round-robin (0: one per
    actor plus the first; 1: everything on one node)."""
    partition: str | None = None
    """SLURM partition (none: the cluster's default)."""
    time_limit: str | None = None
    """The job's time limit in SLURM's formats, e.g. 2:00:00 (none: the partition's default); past it the job is
    stopped, and submitting job.sh again continues the run from its checkpoint."""
    account: str | None = None
    """SLURM account to charge (none: your default)."""
    sbatch: tuple[str, ...] = field(default=(), metadata=SBATCH_FIELD)
    """More sbatch options, as one string, each written as an #SBATCH line; given with = since they start with a
    dash: --sbatch='--exclusive --mem=16G'."""
    secure: bool = True
    """Mutual TLS, a password and an access-control identity per process, written into RUN/secure when the job
    starts (--no-secure: plain TCP, for a trusted network only)."""

    def __post_init__(self) -> None:
        if self.nodes < 0:
            raise ValueError(f"nodes must be 0 (one per actor, plus one) or more, got {self.nodes}")
        if self.time_limit is not None and not _SLURM_TIME.fullmatch(self.time_limit.strip()):
            raise ValueError(
                f"--time-limit {self.time_limit}: not a SLURM time (sbatch would refuse the job); give minutes "
                "(120), hours:minutes:seconds (2:00:00), days-hours (1-12) or days-hours:minutes:seconds (1-00:00:00)"
            )

    def node_count(self, actors: int) -> int:
        return self.nodes or actors + 1

    def check_actors(self, actors: int) -> None:
        """ValueError if some of the job's nodes would get nothing to run: the first runs the learner and the
        router, every other node at least one actor."""
        if self.nodes > actors + 1:
            raise ValueError(
                f"--nodes {self.nodes} for --actors {actors}: the first node runs the learner and each other node "
                f"at least one actor, so {actors + 1} nodes at most ({self.nodes - actors - 1} would sit idle); give "
                f"--nodes {actors + 1}, or --actors {self.nodes - 1}"
            )


_SLURM_TIME = re.compile(r"(?i:unlimited|infinite)|\d+(:\d+){0,2}|\d+-\d+(:\d+){0,2}")
"""sbatch --time's formats: minutes, minutes:seconds, hours:minutes:seconds, days-hours, days-hours:minutes and
days-hours:minutes:seconds."""


def job_script(run_dir: Path, job: SlurmJob, actors: int) -> str:
    """The batch script of a training run in ``run_dir`` (an absolute path on a file system every node sees)."""
    nodes = job.node_count(actors)
    # Every step asks for one task's CPUs: the first node holds the router and the learner, the others the actors.
    per_node = max(2, math.ceil(actors / max(nodes - 1, 1)) + (2 if nodes == 1 else 0))
    lines = [
        "#!/bin/bash",
        "# A training run of ennc-ql, written by `ennc-ql slurm train`: submit it with `sbatch` (again to continue a",
        "# stopped run). The first node runs the router and the learner, the others the actors; a requeued job",
        "# resumes from the run folder's checkpoint. Settings: up.toml, slurm.toml, beside this file.",
        f"#SBATCH --job-name=ennc-ql-{run_dir.name}",
        f"#SBATCH --nodes={nodes}",
        f"#SBATCH --ntasks-per-node={per_node}",
        "#SBATCH --requeue",
        "#SBATCH --open-mode=append",
        f"#SBATCH --output={run_dir}/slurm-%j.out",
    ]
    lines += [f"#SBATCH --{flag}={value}" for flag, value in _named(job) if value is not None]
    lines += [f"#SBATCH {option}" for option in job.sbatch]
    lines += [shlex.join(["exec", sys.executable, "-m", "ennc_ql.cli", "slurm", "run", str(run_dir)])]
    return "\n".join(lines) + "\n"


def _named(job: SlurmJob) -> list[tuple[str, str | None]]:
    return [("partition", job.partition), ("time", job.time_limit), ("account", job.account)]


def write_training_job(config: UpConfig, job: SlurmJob, run_dir: Path) -> Path:
    """The run folder of a training job: every process's configuration (as ``up`` writes them), the job's own
    settings and the job script; returns the script's path."""
    run_dir = run_dir.resolve()
    learner, actors = child_configs(config)
    write_configs(config, learner, actors, run_dir)
    (run_dir / JOB_CONFIG).write_text(dump_config(job))
    script = run_dir / JOB_SCRIPT
    script.write_text(job_script(run_dir, job, config.actors))
    script.chmod(0o755)
    return script


@dataclass(frozen=True, slots=True)
class JobRun:
    """What :func:`run_training_job` returns: the learner's report and what the job's supervision saw."""

    config: UpConfig
    job: SlurmJob
    report: LearnerReport
    run: ProcessRun
    allocation: Allocation
    placement: SlurmPlacement
    recording: RecordingFigures | None


def run_training_job(run_dir: Path, stop: threading.Event) -> JobRun:
    """The job's side (``ennc-ql slurm run``): the run in ``run_dir`` on the allocation this process is part of,
    until the learner is done or ``stop`` is set (the job cancelled, requeued or out of time). Raises
    :class:`~tools.slurm.allocation.SlurmError` outside a job and
    :class:`~tools.cluster.LaunchError` if the learner is given up."""
    config = load_config(UpConfig, file=run_dir / "up.toml")
    job = load_config(SlurmJob, file=run_dir / JOB_CONFIG)
    allocation = Allocation.from_environment()
    learner, actors = child_configs(config)
    placement = SlurmPlacement.of(allocation, [a.actor_id for a in actors])
    recording = run_dir / paths.RECORDING_FILE
    if recording.exists():  # a requeued job: its earlier recording is merged with this run's parts at the end
        earlier = paths.part_file(run_dir, f"before-requeue-{allocation.restarts}")
        earlier.parent.mkdir(exist_ok=True)
        recording.rename(earlier)
    done = run_to_report(
        learner,
        actors,
        run_dir,
        Monitoring(Sink("save", str(recording)), run_dir.name, run_dir),
        namespace=f"run-{run_dir.name}",
        secure=job.secure,
        placement=placement,
        resume=True,
        max_restarts=config.max_restarts,
        stop=stop,
        fresh_only=False,
    )
    if done.report is None:
        raise LaunchError(f"the learner wrote no report; see {run_dir / 'learner.log'}")
    return JobRun(config, job, done.report, done.run, allocation, placement, done.recording)
