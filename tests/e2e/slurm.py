"""A real SLURM of three emulated nodes on this machine, in a temporary folder, for the SLURM tests::

    with LocalSlurm(tmp_path / "slurm") as slurm:        # munged, slurmctld, slurmd -N n1 ... n3
        job_id = ...                                     # sbatch with slurm.env (SLURM_CONF)
        slurm.wait_job(job_id, timeout=300)              # its final JobState
    assert slurm.leftovers() == []                       # every daemon, step and task gone

Nothing outside the folder is touched: its own munge key and socket, ``SLURM_CONF`` pointing at its own
configuration, free ports for slurmctld and the nodes (every node shares 127.0.0.1, each slurmd on its own port).
Debian's ``slurmctld slurmd slurm-client munge`` and root are needed: without them :func:`require_slurm` skips, and
fails instead where ``ENNC_QL_REQUIRE_SLURM=1`` (CI, which installs them: .ci/run).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Self

import psutil

from tests import system

DAEMONS = ("mungekey", "munged", "slurmctld", "slurmd")
CLIENTS = ("sbatch", "srun", "scontrol", "squeue", "scancel")
NODES = ("n1", "n2", "n3")
SBIN = "/usr/sbin:/sbin"
STOP_S = 10.0
"""Seconds a daemon gets to stop on SIGTERM before SIGKILL."""
REQUIRE = system.variable(system.SLURM)
"""Set to 1 where the SLURM tests must run (CI): a missing package is then a failure, not a skip."""


def require_slurm() -> None:
    """Skip (or fail, with ``ENNC_QL_REQUIRE_SLURM=1``) unless the SLURM and munge programs and root are here."""
    path = f"{os.environ.get('PATH', '')}:{SBIN}"
    missing = [name for name in (*DAEMONS, *CLIENTS) if shutil.which(name, path=path) is None]
    reasons = []
    if missing:
        reasons.append(
            f"{', '.join(missing)} not installed (apt-get install -y --no-install-recommends slurmctld slurmd "
            "slurm-client munge)"
        )
    if os.geteuid() != 0:
        reasons.append("slurmd runs job steps as root here: run as root")
    system.require(system.SLURM, "no local SLURM: " + "; ".join(reasons) if reasons else None)


def _free_ports(count: int) -> int:
    """The first of ``count`` consecutive TCP ports free on 127.0.0.1 now."""
    for base in range(17000 + (int(time.time() * 1000) % 3000) * 4, 40000, count):
        try:
            for port in range(base, base + count):
                with socket.socket() as s:
                    s.bind(("127.0.0.1", port))
        except OSError:
            continue
        return base
    raise RuntimeError("no free block of ports")


class LocalSlurm:
    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.env = {**os.environ, "SLURM_CONF": str(folder / "slurm.conf"), "PATH": f"{os.environ['PATH']}:{SBIN}"}
        nodes = [folder / f"slurmd-{node}.pid" for node in NODES]
        self._pid_files = [folder / "munged.pid", folder / "slurmctld.pid", *nodes]

    # -- starting and stopping --------------------------------------------------------------------------------------

    def start(self) -> None:
        d = self.folder
        for sub in ("state", *(f"spool/{n}" for n in NODES)):
            (d / sub).mkdir(parents=True, exist_ok=True)
        self.run("mungekey", "--create", f"--keyfile={d / 'munge.key'}")
        self.run(
            "munged",
            "--force",
            f"--socket={d / 'munge.socket'}",
            f"--key-file={d / 'munge.key'}",
            f"--pid-file={d / 'munged.pid'}",
            f"--log-file={d / 'munged.log'}",
            f"--seed-file={d / 'munge.seed'}",
        )
        ctld = _free_ports(2 + len(NODES))  # one block: the controller's two ports, then one per node
        nodes = ctld + 2
        host = socket.gethostname().split(".")[0]
        (d / "slurm.conf").write_text(
            "\n".join(
                [
                    "ClusterName=enncql-test",
                    f"SlurmctldHost={host}(127.0.0.1)",
                    f"SlurmctldPort={ctld}",
                    f"SlurmdPort={ctld + 1}",
                    "SlurmUser=root",
                    "SlurmdUser=root",
                    "AuthType=auth/munge",
                    "CryptoType=crypto/munge",
                    f"AuthInfo=socket={d / 'munge.socket'}",
                    # No cgroups (a hybrid v1/v2 layout here): processes tracked by their parentage.
                    "ProctrackType=proctrack/linuxproc",
                    "TaskPlugin=task/none",
                    "JobAcctGatherType=jobacct_gather/none",
                    "AccountingStorageType=accounting_storage/none",
                    "MpiDefault=none",
                    "MailProg=/bin/true",
                    "SchedulerType=sched/backfill",
                    "SchedulerParameters=bf_interval=1",
                    "SelectType=select/cons_tres",
                    "SelectTypeParameters=CR_Core",
                    "ReturnToService=2",
                    "SlurmdParameters=config_overrides",
                    # A cancelled or requeued job's tasks get SIGTERM, then SIGKILL after this many seconds.
                    "KillWait=30",
                    f"StateSaveLocation={d / 'state'}",
                    f"SlurmdSpoolDir={d / 'spool'}/%n",
                    f"SlurmctldPidFile={d / 'slurmctld.pid'}",
                    f"SlurmdPidFile={d}/slurmd-%n.pid",
                    f"SlurmctldLogFile={d / 'slurmctld.log'}",
                    f"SlurmdLogFile={d}/slurmd-%n.log",
                    f"NodeName=n[1-3] NodeHostname={host} NodeAddr=127.0.0.1 Port=[{nodes}-{nodes + 2}] CPUs=2 "
                    "RealMemory=1000",
                    "PartitionName=main Nodes=n[1-3] Default=YES MaxTime=INFINITE State=UP",
                ]
            )
            + "\n"
        )
        self.run("slurmctld")
        for node in NODES:
            self.run("slurmd", "-N", node)
        self.wait_for(lambda: self.idle_nodes() == len(NODES), 60, "three idle nodes")

    def stop(self) -> None:
        """Cancel every job, then stop the nodes, the controller and munged by their pid files, and wait them out."""
        if (self.folder / "slurmctld.pid").exists():
            jobs = self.query("squeue", "--noheader", "--format=%i").split()
            if jobs:
                self.query("scancel", *jobs)
                self.wait_for(lambda: not self.query("squeue", "--noheader", "--format=%i").strip(), 60, "no jobs")
        nodes, controller, munge = self._pid_files[2:], self._pid_files[1], self._pid_files[0]
        for group in (nodes, [controller], [munge]):  # the nodes together, then the controller, munged last
            procs = []
            for pid in (self._pid(pid_file) for pid_file in group):
                try:
                    procs.append(psutil.Process(pid or -1))
                except (psutil.NoSuchProcess, ValueError):
                    continue
            for proc in procs:
                proc.terminate()
            _, alive = psutil.wait_procs(procs, STOP_S)
            for proc in alive:  # a node whose controller is gone may wait for it: no longer
                proc.kill()
            psutil.wait_procs(alive, STOP_S)

    def leftovers(self) -> list[str]:
        """Processes of this cluster still running: any whose command line or environment names its folder (the
        daemons, slurmstepd, every task), and the daemons by their pid files."""
        left = []
        for proc in psutil.process_iter(["pid", "cmdline"]):
            try:
                text = " ".join(proc.info["cmdline"] or [])
                environ = proc.environ() if proc.pid != os.getpid() else {}
            except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess):
                continue
            if str(self.folder) in text or environ.get("SLURM_CONF") == self.env["SLURM_CONF"]:
                left.append(f"{proc.pid}: {text}")
        left += [f"{f.stem} {p}" for f in self._pid_files if (p := self._pid(f)) is not None and psutil.pid_exists(p)]
        return left

    def __enter__(self) -> Self:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    # -- using it ---------------------------------------------------------------------------------------------------

    def run(self, *argv: str) -> str:
        done = subprocess.run(argv, env=self.env, capture_output=True, text=True, timeout=60, check=False)
        assert done.returncode == 0, f"{' '.join(argv)}: {done.stderr}"
        return done.stdout

    def query(self, *argv: str) -> str:
        """A client command's output, empty if it failed (the controller may be going)."""
        done = subprocess.run(argv, env=self.env, capture_output=True, text=True, timeout=60, check=False)
        return done.stdout if done.returncode == 0 else ""

    def idle_nodes(self) -> int:
        return len(self.query("sinfo", "--noheader", "--Node", "--states=idle", "--format=%N").split())

    def job(self, job_id: str) -> dict[str, str]:
        """``scontrol show job``'s fields (empty once the controller forgot the job)."""
        text = self.query("scontrol", "--oneliner", "show", "job", job_id)
        return dict(word.split("=", 1) for word in text.split() if "=" in word)

    def wait_job(self, job_id: str, timeout: float, states: tuple[str, ...] = ("COMPLETED", "FAILED")) -> str:
        """Poll the job until it is in one of ``states`` (or any end state); that state."""
        ended = (*states, "CANCELLED", "TIMEOUT", "NODE_FAIL", "OUT_OF_MEMORY")
        state = ""

        def done() -> bool:
            nonlocal state
            state = self.job(job_id).get("JobState", "")
            return state in ended

        self.wait_for(done, timeout, f"job {job_id} to reach {'/'.join(states)}")
        return state

    @staticmethod
    def wait_for(predicate: Callable[[], bool], timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return
            time.sleep(0.2)
        raise AssertionError(f"timed out waiting for {what}")

    @staticmethod
    def _pid(path: Path) -> int | None:
        try:
            return int(path.read_text().strip())
        except (OSError, ValueError):
            return None
