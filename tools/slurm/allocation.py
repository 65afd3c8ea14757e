"""The SLURM allocation a job runs in, and where each process of a training run goes in it::

    allocation = Allocation.from_environment()       # inside a job: its nodes, their addresses, this node
    placement = SlurmPlacement.of(allocation, ["actor-0", "actor-1"])
    placement.command("actor-1", argv)               # srun ... --nodelist=<its node> argv
    placement.host                                   # the first node's address: the router listens there

The router and the learner run on the node the batch script runs on (SLURM's first node of the allocation), the
actors round-robin on the others (on that node too when the allocation has only one). Node names come from
``scontrol show hostnames $SLURM_JOB_NODELIST`` and addresses from each node's ``NodeAddr``: a node's name need not
resolve, and several emulated nodes may share one address (then only the router listens, on one port).
"""

from __future__ import annotations

import os
import signal
import socket
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from protocol.security import ROUTER
from tools.cluster import Placement
from tools.cluster.processes import LEARNER
from tools.slurm.sbatch import SlurmError, slurm_command


@dataclass(frozen=True, slots=True)
class Allocation:
    job_id: str
    nodes: tuple[str, ...]
    """The allocation's node names, in SLURM's order."""
    here: str
    """The node this process (the batch script) runs on."""
    addresses: Mapping[str, str]
    """Node name -> its address (``NodeAddr``)."""
    restarts: int = 0
    """How many times the job was requeued before this run of it."""

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] | None = None) -> Allocation:
        env = os.environ if environ is None else environ
        missing = [name for name in ("SLURM_JOB_ID", "SLURM_JOB_NODELIST", "SLURMD_NODENAME") if name not in env]
        if missing:
            raise SlurmError(
                f"not inside a SLURM job ({', '.join(missing)} not set): submit the job script with sbatch"
            )
        nodelist = env["SLURM_JOB_NODELIST"]
        nodes = tuple(slurm_command(["scontrol", "show", "hostnames", nodelist]).split())
        addresses: dict[str, str] = {}
        for line in slurm_command(["scontrol", "--oneliner", "show", "node", nodelist]).splitlines():
            fields = dict(word.split("=", 1) for word in line.split() if "=" in word)
            if "NodeName" in fields:
                addresses[fields["NodeName"]] = fields.get("NodeAddr", fields["NodeName"])
        return cls(
            job_id=env["SLURM_JOB_ID"],
            nodes=nodes,
            here=env["SLURMD_NODENAME"],
            addresses={node: addresses.get(node, node) for node in nodes},
            restarts=int(env.get("SLURM_RESTART_COUNT", "0") or 0),
        )


@dataclass(frozen=True, slots=True)
class SlurmPlacement(Placement):
    """Every child a job step on its node (``srun``), stopped with SIGUSR1, which ``srun`` forwards to its task (it
    turns a SIGTERM into killing the step); the router and the learner on the batch script's node."""

    node_of: Mapping[str, str] = field(default_factory=dict)
    """Child name -> the node it runs on."""
    stop_signal: int = signal.SIGUSR1
    owns_children: bool = False
    """The tasks are slurmstepd's children on their nodes, and the job's end takes them all."""

    @classmethod
    def of(cls, allocation: Allocation, actor_ids: Sequence[str]) -> SlurmPlacement:
        others = [node for node in allocation.nodes if node != allocation.here] or [allocation.here]
        node_of = {ROUTER: allocation.here, LEARNER: allocation.here}
        node_of.update({actor: others[i % len(others)] for i, actor in enumerate(actor_ids)})
        names = tuple(dict.fromkeys((allocation.here, socket.gethostname())))
        return cls(host=allocation.addresses[allocation.here], names=names, node_of=node_of)

    def command(self, name: str, argv: list[str]) -> list[str]:
        # --overlap: a step shares the allocation's CPUs with the others, so a restarted one never waits for the
        # resources of the step it replaces to be released.
        node = self.node_of[name]
        return ["srun", "--overlap", "--nodes=1", "--ntasks=1", f"--nodelist={node}", f"--job-name={name}", *argv]
