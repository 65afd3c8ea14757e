"""The SLURM figures of docs/performance.md, measured on a local SLURM of three emulated nodes (tests/e2e/slurm.py),
printed as one JSON object: a training job's start to its first policy, a learner SIGKILLed inside the job and under
``up`` (kill to the resumed learner's first broadcast), and a tiny sweep as a job array against the local ``--jobs``
path.

    .venv/bin/python scripts/slurm_figures.py [--duration 60] [--kills 2]

Needs root and Debian's slurmctld, slurmd, slurm-client and munge (as the SLURM tests do). Every emulated node
shares this machine's cores, so the array cannot be faster than the local path here: the figure is its overhead.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.e2e.cluster import checkpoint_version
from tests.e2e.slurm import LocalSlurm
from tools.cluster import ennc_ql_argv

SMALL = [
    "--actors=2",
    "--actor-arenas=100",
    "--learner-min-tuples=50000",
    "--learner-phase1-n-cycles=50",
    "--learner-phase1-max-patterns=5000",
    "--learner-eval-interval=1000",
]
"""2 actors x 100 arenas; the first fit (two iterations, 50 ENNC cycles on at most 5 000 tuples per action) once
50 000 tuples are in."""
TIMEOUT_S = 300.0
SWEEP = [
    "ablate",
    "ennc-ql-collab-option2",
    "--set=budget.phase2.alpha=0.05,0.1,0.2",
    *(f"--set=budget.{kv}" for kv in ("arenas=64", "explore_trials=1", "phase2_trials=4", "test_trials=2")),
    "--processes=2",
]


def log_time(path: Path, text: str) -> float | None:
    """Wall time of the first line of a process log holding ``text``."""
    for line in path.read_text(errors="replace").splitlines():
        if text in line:
            return datetime.datetime.strptime(line[:23], "%Y-%m-%d %H:%M:%S,%f").timestamp()
    return None


def kill_learner_after_checkpoints(run_dir: Path, kills: int, every: float) -> list[float]:
    """SIGKILL the learner just after a checkpoint landed, ``kills`` times, ``every`` seconds apart (a minute or
    more: each restart then waits the shortest back-off); the wall time of each kill."""
    done: list[float] = []
    while len(done) < kills:
        earliest = time.monotonic() + (every if done else 0.0)
        wait(lambda t=earliest: checkpoint_version(run_dir) >= 1 and time.monotonic() >= t, "a checkpointed policy")
        landed = (run_dir / "checkpoint.npz").stat().st_mtime_ns
        wait(lambda t=landed: (run_dir / "checkpoint.npz").stat().st_mtime_ns != t, "the next checkpoint")
        pid = learner_task(run_dir)
        os.kill(pid, signal.SIGKILL)
        done.append(time.time())
    return done


def wait(predicate: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not predicate():
        if time.monotonic() > deadline:
            raise RuntimeError(f"no {what} within {TIMEOUT_S:.0f} s: a longer --duration?")
        time.sleep(0.05)


def learner_task(run_dir: Path) -> int:
    needle = str(run_dir / "learner.toml").encode()
    for entry in Path("/proc").iterdir():
        try:
            cmdline = (entry / "cmdline").read_bytes()
        except OSError:
            continue
        if entry.name.isdigit() and needle in cmdline and not cmdline.startswith(b"srun"):
            return int(entry.name)
    raise RuntimeError("no learner process")


def back_in(report: dict[str, Any], kills: list[float]) -> list[float]:
    """Seconds from each kill to the resumed learner's first broadcast."""
    return [round(r["wall_time"] - k, 2) for r, k in zip(report["resumes"][-len(kills) :], kills, strict=True)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of training of the job and of up")
    parser.add_argument("--kills", type=int, default=2, help="learner kills under up, a minute apart")
    parser.add_argument(
        "--defaults",
        action="store_true",
        help="train the job on the learner's and the actors' defaults instead of the small settings",
    )
    parser.add_argument("--job-only", action="store_true", help="only the training job: no sweep, no up")
    args = parser.parse_args()
    settings = [] if args.defaults else SMALL
    figures: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="slurm-figures-") as tmp:
        work = Path(tmp)
        with LocalSlurm(work / "slurm") as slurm:
            # A training job: submitted, one learner kill inside it, to its end.
            run_dir = work / "runs" / "job"
            submitted = time.time()
            argv = ennc_ql_argv("slurm", "train", "--nodes=3", f"--duration={args.duration}", *settings)
            out = slurm.run(*argv, f"--runs={work / 'runs'}", "--run-id=job", "--submit", "--json")
            job_id = json.loads(out)["job_id"]
            kills = kill_learner_after_checkpoints(run_dir, 1, 0.0)
            slurm.wait_job(job_id, timeout=args.duration + 600)
            report = json.loads((run_dir / "report.json").read_text())
            start = slurm.job(job_id)["StartTime"]
            started = datetime.datetime.strptime(start, "%Y-%m-%dT%H:%M:%S").timestamp()
            first_fit = log_time(run_dir / "learner.log", "phase 1 done")
            assert first_fit is not None
            figures["job"] = {
                "submit_to_start_s": round(started - submitted, 1),
                "start_to_first_policy_s": round(first_fit - started, 1),
                "driver_to_first_policy_s": report["first_policy_s"],
                "learner_up_s": round((log_time(run_dir / "learner.log", "started (policy") or 0.0) - started, 1),
                "learner_kill_to_first_broadcast_s": back_in(report, kills),
                "learner_restarts": report["learner_restarts"],
                "tuples_by_actor": report["tuples_by_actor"],
                "actors_sent": report["actors_sent"],
                "gaps": report["gaps"],
                "policy_versions": report["policy_versions"],
            }
            figures["job"]["settings"] = "defaults" if args.defaults else "small"
            if args.job_only:
                print(json.dumps(figures, indent=2))
                return
            # A sweep as an array, against the same variants on local workers.
            t = time.monotonic()
            slurm.run(*ennc_ql_argv(*SWEEP, "--slurm", f"--out={work / 'array'}"))
            array_s = time.monotonic() - t
        t = time.monotonic()
        subprocess.run(ennc_ql_argv(*SWEEP, "--jobs=2", f"--out={work / 'local'}"), check=True, capture_output=True)
        local_s = time.monotonic() - t
        same = (work / "array" / "results.md").read_text() == (work / "local" / "results.md").read_text()
        figures["sweep"] = {"tasks": 6, "array_s": round(array_s, 1), "local_jobs2_s": round(local_s, 1), "same": same}
        # The learner of up, killed just after a checkpoint a minute apart.
        argv = ennc_ql_argv("up", f"--duration={args.duration + 70 * args.kills}", *SMALL, "--rerun=off", "--json")
        up = subprocess.Popen(
            [*argv, f"--runs={work / 'runs'}", "--run-id=up"],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        try:
            wait(lambda: (work / "runs" / "up" / "learner.toml").exists(), "run folder of up")
            kills = kill_learner_after_checkpoints(work / "runs" / "up", args.kills, 65.0)
            report = json.loads(up.communicate()[0])
        finally:
            if up.poll() is None:
                up.send_signal(signal.SIGINT)  # up stops its children on the way out
                up.wait()
        figures["up"] = {
            "learner_kill_to_first_broadcast_s": back_in(report, kills),
            "learner_restarts": report["learner_restarts"],
            "resumes": report["resumes"],
            "policy_versions": report["policy_versions"],
            "gaps": report["gaps"],
        }
    print(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
