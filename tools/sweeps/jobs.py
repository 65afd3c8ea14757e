"""The learning processes ``reproduce`` and ``ablate`` run: one :class:`Job` per process, run by a :class:`Backend`
chosen once by the command (:class:`LocalProcesses` here, one at a time or in worker processes, or
:class:`tools.slurm.array.SlurmArray`), with a progress bar over them::

    with ProgressBar("reproduce", total=len(todo), unit="jobs") as bar:
        outcomes = LocalProcesses(jobs=2).learn(todo, JobsBar(bar))      # [(job, outcome), ...]
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from algorithm.experiments import METHODS, Budget, Outcome, Progress, train
from algorithm.policy import LostBehaviour
from sim import ScenarioConfig
from sim.formulation import Formulation
from tools.progress import ProgressBar


@dataclass(frozen=True, slots=True)
class Job:
    """One learning process to run: a method under a budget and scenario, tested with a lost-robot behaviour."""

    method: str
    budget: Budget
    seed: int
    scenario: ScenarioConfig
    lost_behaviour: LostBehaviour = "wander"
    variant: int = 0
    """Which of a sweep's variants this process belongs to (``ennc-ql ablate``)."""
    formulation: Formulation | None = field(
        default=None, metadata={"parse": Formulation.parse, "format": lambda f: f.text, "metavar": "FORMULATION"}
    )
    """What the process learns on instead of the method's own formulation, if given (a job file writes it as
    featurizer/reward/actions/act_every/rules); its act_every is the steps between decisions in the test trials
    (none: action_steps)."""

    @property
    def label(self) -> str:
        return f"{self.method}[{self.seed}]" if not self.variant else f"{self.method} v{self.variant}[{self.seed}]"

    def run(self, progress: Progress | None = None) -> Outcome:
        return train(
            METHODS[self.method],
            self.budget,
            self.seed,
            self.scenario,
            progress,
            lost_behaviour=self.lost_behaviour,
            formulation=self.formulation,
        )


def _train_job(job: Job) -> tuple[Job, Outcome]:
    """One learning process in a worker: one torch thread each, so jobs share the cores instead of fighting."""
    import torch  # here, in the worker: every command line builds this command's parser, and most never fit

    torch.set_num_threads(1)
    return job, job.run()


class JobsBar:
    """The bar's state: jobs finished, the running job's stage and the latest coverage measured."""

    def __init__(self, bar: ProgressBar) -> None:
        self.bar = bar
        self.done = 0
        self.latest = ""

    def running(self, status: str) -> None:
        self.bar.show(status=status + (f"; latest {self.latest}" if self.latest else ""))

    def finished(self, message: str) -> None:
        self.done += 1
        self.latest = message
        self.bar.mark(message, n=self.done)


def run_jobs(todo: Sequence[Job], jobs: int, progress: JobsBar) -> list[tuple[Job, Outcome]]:
    """Every learning process of ``todo``, ``jobs`` at a time (in worker processes when more than one)."""
    outcomes: list[tuple[Job, Outcome]] = []
    if jobs > 1 and todo:
        progress.running(f"{len(todo)} learning processes on {jobs} workers")
        with multiprocessing.get_context("spawn").Pool(jobs) as pool:
            for job, outcome in pool.imap_unordered(_train_job, todo):
                outcomes.append((job, outcome))
                progress.finished(f"{job.label}: {outcome.coverage_mean:.2f}%")
                # Workers report nothing until a process ends: the bar can only count what is left.
                progress.running(f"{len(todo) - len(outcomes)} learning processes left")
        return outcomes
    for job in todo:

        def stage(message: str, label: str = job.label) -> None:
            progress.running(f"{label}: {message}")

        outcomes.append((job, job.run(stage)))
        progress.finished(f"{job.label}: {outcomes[-1][1].coverage_mean:.2f}%")
    return outcomes


class Backend(Protocol):
    """Where a sweep's learning processes run: every job of ``todo`` learned, its outcome returned beside it, and
    ``progress`` told as each one finishes."""

    def learn(self, todo: Sequence[Job], progress: JobsBar) -> list[tuple[Job, Outcome]]: ...


@dataclass(frozen=True, slots=True)
class LocalProcesses:
    """The learning processes on this machine, ``jobs`` at a time (in worker processes when more than one)."""

    jobs: int = 1

    def learn(self, todo: Sequence[Job], progress: JobsBar) -> list[tuple[Job, Outcome]]:
        return run_jobs(todo, self.jobs, progress)


ONE_AT_A_TIME = LocalProcesses()
"""The sweeps' default backend: one learning process at a time, here."""
