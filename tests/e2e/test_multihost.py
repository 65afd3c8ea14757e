"""Multi-host run without Docker: router, learner and two actors each on its own network namespace.

Every process gets its own network stack and address, as on separate machines: namespaces ``<prefix>-<host>``,
each with a veth link to a bridge inside one more namespace of the test (the "switch"), addresses in the
private 10.213.7.0/24. Everything is created inside namespaces the test owns, so the host's own interfaces,
addresses and routes are never touched; the namespaces are deleted afterwards (deleting a namespace destroys
its veth ends). Needs iproute2 and the privilege to create namespaces (root); the test skips without them.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests import system
from tests.e2e import ACTOR_BUDGET, LEARNER_BUDGET, Processes, ennc_ql

pytestmark = pytest.mark.slow

PREFIX = "ennc-e2e"
SUBNET = "10.213.7"
HOSTS = ("router", "learner", "actor-0", "actor-1")
PORT = 7447  # each namespace has its own port space: zenoh's registered port is free in the router's


def ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, timeout=10)


def delete_stale_namespaces() -> None:
    """Remove namespaces a killed earlier run of this test left behind (their pid is gone)."""
    listing = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, timeout=10).stdout
    for name in (line.split()[0] for line in listing.splitlines() if line.startswith(PREFIX + "-")):
        pid = name.split("-")[2]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=10)


class Network:
    """The namespaces of one test run: ``ns[host]`` and ``addr[host]`` for every host in HOSTS."""

    def __init__(self) -> None:
        tag = f"{PREFIX}-{os.getpid()}"
        self.switch = f"{tag}-switch"
        self.ns = {host: f"{tag}-{host}" for host in HOSTS}
        self.addr = {host: f"{SUBNET}.{i + 1}" for i, host in enumerate(HOSTS)}
        self.created: list[str] = []

    def add_namespace(self, name: str) -> None:
        ip("netns", "add", name)
        self.created.append(name)
        ip("-n", name, "link", "set", "lo", "up")

    def build(self) -> None:
        self.add_namespace(self.switch)
        ip("-n", self.switch, "link", "add", "br0", "type", "bridge")
        ip("-n", self.switch, "link", "set", "br0", "up")
        for i, host in enumerate(HOSTS):
            ns = self.ns[host]
            self.add_namespace(ns)
            # Both ends are created inside our namespaces: the host's root namespace never sees them.
            ip("-n", self.switch, "link", "add", f"port{i}", "type", "veth", "peer", "name", "eth0", "netns", ns)
            ip("-n", self.switch, "link", "set", f"port{i}", "master", "br0", "up")
            ip("-n", ns, "addr", "add", f"{self.addr[host]}/24", "dev", "eth0")
            ip("-n", ns, "link", "set", "eth0", "up")

    def delete(self) -> None:
        for name in reversed(self.created):
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=10)
        self.created.clear()

    def run(self, host: str, argv: list[str]) -> list[str]:
        """``argv`` run on ``host`` (``ip netns exec`` execs it, so the pid is the command's own)."""
        return ["ip", "netns", "exec", self.ns[host], *argv]


@pytest.fixture
def network() -> Iterator[Network]:
    if shutil.which("ip") is None:
        system.require(system.NETNS, "iproute2 is not installed (no `ip` command): cannot create network namespaces")
    delete_stale_namespaces()
    net = Network()
    try:
        try:
            net.build()
        except subprocess.CalledProcessError as exc:
            if net.created:
                raise  # namespaces can be made here, so this is a failure, not a missing privilege
            why = f"cannot create network namespaces (needs root or CAP_SYS_ADMIN): {exc.stderr.strip()}"
            system.require(system.NETNS, why)
        yield net
    finally:
        net.delete()


def test_router_learner_and_actors_on_separate_hosts(network: Network, tmp_path: Path) -> None:
    router = f"tcp/{network.addr['router']}:{PORT}"
    client = ["--mode=client", f"--connect={router}", "--no-multicast-scouting"]
    with Processes(tmp_path) as procs:
        procs.start(
            "router",
            network.run("router", ennc_ql("router", f"--listen={router}", "--no-multicast-scouting")),
        )
        procs.start(
            "learner",
            network.run("learner", ennc_ql("learner", *client, f"--run-dir={tmp_path / 'run'}", *LEARNER_BUDGET)),
        )
        for actor in ("actor-0", "actor-1"):
            procs.start(actor, network.run(actor, ennc_ql("actor", *client, f"--actor-id={actor}", *ACTOR_BUDGET)))

        results, report = procs.stop_after_first_policy(["actor-0", "actor-1"])
        counters = dict(zip(("actor-0", "actor-1"), results, strict=True))
        assert procs.procs["router"].poll() is None, "the router died\n" + procs.log_tail("router")
    router_log = (tmp_path / "router.log").read_text()

    # The learner and both actors reached each other through the router, from their own addresses.
    assert len(set(re.findall(r"client (\w+) connected", router_log))) == 3, router_log
    assert report["actors"] == ["actor-0", "actor-1"]
    for actor, c in counters.items():
        assert c["tuples_sent"] > 0
        assert report["tuples_by_actor"][actor] == c["tuples_sent"]
        assert c["policy_version"] >= 1 and c["policies_applied"] >= 1
        assert c["outbox"] == 0  # everything it sent was acknowledged
    assert report["gaps"] == 0
    assert report["policy_version"] >= 1
