"""The hosts of a chaos run with network faults: the router, the learner and every actor each in a network namespace
of its own, linked by veth pairs to a bridge in one more namespace (the switch), with addresses in a private /24
that exists only inside them. Chaos's own sessions and its link proxies (:mod:`~tools.chaos.proxy`) live on the
router's host; a partition drops everything on one host's link with iptables rules inside its namespace. Nothing
is created outside these namespaces, and deleting them at the end removes every veth and rule with them. Usage::

    reason = unavailable()                         # None, or why namespaces cannot be made here
    net = Network(["router", "learner", "actor-0"])
    with net.built():
        net.enter("router")                        # this thread (and the threads it starts) on the router's host
        argv = net.on("actor-0", argv)             # a command line run on actor-0's host
        net.partition("actor-0"); net.heal("actor-0")
"""

from __future__ import annotations

import ctypes
import logging
import os
import shutil
import subprocess
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

log = logging.getLogger("tools.chaos")  # one name for the package: its lines read "tools.chaos: ..."

PREFIX = "ennc-chaos"
SUBNET = "10.213.8"
"""A private /24 that exists only inside the run's namespaces (tests/e2e/test_multihost.py uses 10.213.7)."""
_CLONE_NEWNET = 0x40000000
_NETNS_DIR = Path("/run/netns")


class NetworkError(RuntimeError):
    """A namespace, link or rule that could not be made (the run cannot start)."""


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10, check=False)
    if done.returncode != 0:
        raise NetworkError(f"`ip {' '.join(args)}` failed: {done.stderr.strip()}")


def unavailable() -> str | None:
    """Why network namespaces, veth links and iptables rules cannot be made here, or None if they can."""
    missing = [tool for tool in ("ip", "iptables") if shutil.which(tool) is None]
    if missing:
        return f"{' and '.join(missing)} not installed (apt-get install -y iproute2 iptables)"
    probe = f"{PREFIX}-{os.getpid()}-probe"
    try:
        _ip("netns", "add", probe)
    except NetworkError as exc:
        return f"cannot create network namespaces (needs root or CAP_SYS_ADMIN): {exc}"
    try:
        subprocess.run(
            ["ip", "netns", "exec", probe, "iptables", "-S"], check=True, capture_output=True, text=True, timeout=10
        )
    except subprocess.CalledProcessError as exc:
        return f"iptables does not work inside a network namespace: {exc.stderr.strip()}"
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=10)
    return None


def delete_stale() -> None:
    """Remove namespaces that a killed earlier chaos run left behind (their pid is gone)."""
    for path in _NETNS_DIR.glob(f"{PREFIX}-*") if _NETNS_DIR.exists() else []:
        pid = path.name.removeprefix(PREFIX + "-").split("-")[0]
        if pid.isdigit() and not Path(f"/proc/{pid}").exists():
            subprocess.run(["ip", "netns", "del", path.name], capture_output=True, timeout=10)


class Network:
    """The namespaces of one run: ``address[host]`` for every host, ``namespace[host]`` once built."""

    def __init__(self, hosts: Sequence[str]) -> None:
        tag = f"{PREFIX}-{os.getpid()}"
        self.switch = f"{tag}-switch"
        self.namespace = {host: f"{tag}-{i}" for i, host in enumerate(hosts)}
        self.address = {host: f"{SUBNET}.{i + 1}" for i, host in enumerate(hosts)}
        self._created: list[str] = []
        self._home: int | None = None
        """This process's own namespace while a thread of it is on another host (:meth:`enter`)."""

    @contextmanager
    def built(self) -> Iterator[Network]:
        """The namespaces, links and addresses; every one deleted on the way out (this thread back home first)."""
        delete_stale()
        try:
            self._add(self.switch)
            _ip("-n", self.switch, "link", "add", "br0", "type", "bridge")
            _ip("-n", self.switch, "link", "set", "br0", "up")
            for i, (host, ns) in enumerate(self.namespace.items()):
                self._add(ns)
                # Both ends are made inside our namespaces: the host's own never sees them.
                _ip("-n", self.switch, "link", "add", f"port{i}", "type", "veth", "peer", "name", "eth0", "netns", ns)
                _ip("-n", self.switch, "link", "set", f"port{i}", "master", "br0", "up")
                _ip("-n", ns, "addr", "add", f"{self.address[host]}/24", "dev", "eth0")
                _ip("-n", ns, "link", "set", "eth0", "up")
            log.info("network: %s", ", ".join(f"{h} {a}" for h, a in self.address.items()))
            yield self
        finally:
            self.leave()
            for name in reversed(self._created):
                subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=10)
            self._created.clear()

    def _add(self, name: str) -> None:
        _ip("netns", "add", name)
        self._created.append(name)
        _ip("-n", name, "link", "set", "lo", "up")

    def on(self, host: str, argv: list[str]) -> list[str]:
        """``argv`` run on ``host`` (``ip netns exec`` execs it: the pid is the command's own)."""
        return ["ip", "netns", "exec", self.namespace[host], *argv]

    def enter(self, host: str) -> None:
        """Move the calling thread onto ``host``: the sockets it (or a thread it starts later) opens are there."""
        libc = ctypes.CDLL(None, use_errno=True)
        if self._home is None:
            self._home = os.open("/proc/self/ns/net", os.O_RDONLY)
        fd = os.open(_NETNS_DIR / self.namespace[host], os.O_RDONLY)
        try:
            if libc.setns(fd, _CLONE_NEWNET) != 0:
                raise OSError(ctypes.get_errno(), f"setns into {self.namespace[host]}")
        finally:
            os.close(fd)

    def leave(self) -> None:
        """The calling thread back in this process's own namespace (threads started meanwhile stay where they are)."""
        if self._home is not None:
            ctypes.CDLL(None, use_errno=True).setns(self._home, _CLONE_NEWNET)
            os.close(self._home)
            self._home = None

    def partition(self, host: str) -> None:
        """Drop every packet on ``host``'s link, both ways: its connections hang as behind a cut cable."""
        for rule in (["INPUT", "-i", "eth0"], ["OUTPUT", "-o", "eth0"]):
            self._iptables(host, "-I", *rule, "-j", "DROP")

    def heal(self, host: str) -> None:
        self._iptables(host, "-F")

    def _iptables(self, host: str, *args: str) -> None:
        done = subprocess.run(self.on(host, ["iptables", *args]), capture_output=True, text=True, timeout=10)
        if done.returncode != 0:
            raise NetworkError(f"`iptables {' '.join(args)}` on {host} failed: {done.stderr.strip()}")
