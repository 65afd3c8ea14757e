"""The pieces of chaos's network faults: the shaping link proxy on loopback, and the hosts (network namespaces) with
a partition, where this machine lets them be made."""

from __future__ import annotations

import os
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests import system
from tools.chaos.network import Network, unavailable
from tools.chaos.proxy import CHUNK_BYTES, Proxies, Shaping


@pytest.fixture
def echo() -> Iterator[int]:
    """A TCP echo server on loopback (one thread per connection): its port."""
    server = socket.create_server(("127.0.0.1", 0))

    def serve(conn: socket.socket) -> None:
        with conn:
            while data := conn.recv(65536):
                conn.sendall(data)

    def accept() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return  # closed
            threading.Thread(target=serve, args=(conn,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    try:
        yield server.getsockname()[1]
    finally:
        server.close()


def round_trip(port: int, payload: bytes) -> tuple[bytes, float]:
    """``payload`` sent through the proxy on ``port`` and echoed back: what came back and the seconds it took."""
    with socket.create_connection(("127.0.0.1", port), timeout=30) as conn:
        began = time.monotonic()
        conn.sendall(payload)
        got = b""
        while len(got) < len(payload):
            got += conn.recv(65536)
        return got, time.monotonic() - began


def test_the_proxy_relays_intact_and_holds_chunks_back_as_shaped(echo: int) -> None:
    proxies = Proxies(("127.0.0.1", echo)).start()
    try:
        port = proxies.add("actor-0", "127.0.0.1")
        payload = os.urandom(5 * CHUNK_BYTES + 123)
        assert round_trip(port, payload)[0] == payload
        proxies.shape(Shaping(delay_s=0.15))  # each way: at least 0.3 s there and back
        got, seconds = round_trip(port, b"ping")
        assert got == b"ping" and seconds >= 0.3
        proxies.shape(Shaping(loss=1.0, rto_s=0.25))  # every chunk held back one timeout, each way
        got, seconds = round_trip(port, b"pong")
        assert got == b"pong" and seconds >= 0.5
        proxies.shape(Shaping())
        relayed = proxies.relayed()["actor-0"]
        assert relayed == {"up": len(payload) + 8, "down": len(payload) + 8}
    finally:
        proxies.close()
    assert not [t for t in threading.enumerate() if t.name == "chaos-links"]


def test_a_connection_to_a_router_that_is_down_is_dropped(echo: int) -> None:
    """The client sees the link close, as it would see the router refuse it, and retries."""
    with socket.create_server(("127.0.0.1", 0)) as probe:
        closed_port = probe.getsockname()[1]
    proxies = Proxies(("127.0.0.1", closed_port)).start()
    try:
        port = proxies.add("learner", "127.0.0.1")
        with socket.create_connection(("127.0.0.1", port), timeout=10) as conn:
            try:
                got = conn.recv(1)
            except ConnectionResetError:
                got = b""  # an abort may arrive as a reset: the link is gone either way
            assert got == b""
    finally:
        proxies.close()


def test_hosts_reach_each_other_until_a_partition_and_leave_nothing_behind(tmp_path: Path) -> None:
    reason = unavailable()
    system.require(system.NETNS, None if reason is None else f"no network namespaces here: {reason}")
    net = Network(["router", "actor-0"])
    server = ["python3", "-c", PORT_SERVER, net.address["router"]]
    with net.built():
        listening = subprocess.Popen(net.on("router", server), stdout=subprocess.PIPE, text=True)
        try:
            assert listening.stdout is not None and listening.stdout.readline().strip() == "ready"
            assert reach(net, "actor-0", net.address["router"]) == 0
            net.partition("actor-0")
            assert reach(net, "actor-0", net.address["router"]) != 0
            net.heal("actor-0")
            assert reach(net, "actor-0", net.address["router"]) == 0
            # This thread on the router's host: loopback there is the router's, not this machine's.
            net.enter("router")
            with socket.create_connection((net.address["router"], 18447), timeout=5):
                pass
        finally:
            net.leave()
            listening.kill()
            listening.wait()
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True).stdout
    assert not [name for name in [net.switch, *net.namespace.values()] if name in listed]


PORT_SERVER = """
import socket, sys
server = socket.create_server((sys.argv[1], 18447))
print("ready", flush=True)
while True:
    server.accept()[0].close()
"""


def reach(net: Network, host: str, address: str) -> int:
    """Exit status of a TCP connection attempt from ``host`` to ``address`` (2 s at most)."""
    probe = f"import socket; socket.create_connection(({address!r}, 18447), timeout=2).close()"
    return subprocess.run(net.on(host, ["python3", "-c", probe]), capture_output=True, timeout=30).returncode


@pytest.mark.parametrize("secure", [False, True], ids=["plain", "secure"])
def test_with_network_faults_every_process_runs_on_its_host_through_its_link(secure: bool, tmp_path: Path) -> None:
    """The command lines chaos starts: each process in its namespace, each client dialling its own link's proxy on
    the router's host (the only endpoint it has), shared memory off everywhere, the router's certificate valid for
    the address clients dial."""
    import json

    from cryptography import x509

    from ennc_ql.cli import build_parser
    from protocol import config_from_args
    from tools.chaos import Chaos, ChaosOptions
    from tools.cluster import UP_PRESETS, UpConfig
    from tools.config import load_config

    options = ChaosOptions(60.0, secure, 5.0, ("partition", "delay"), 5.0)
    chaos = Chaos(options, load_config(UpConfig, defaults=UP_PRESETS), tmp_path, "t", "chaos-t")
    assert chaos.network is not None
    router = chaos.network.address["router"]
    chaos.links = {"learner": 30001, "actor-0": 30002, "actor-1": 30003}
    scheme = "tls" if secure else "tcp"
    for ident, argv in [("learner", chaos.learner_argv(resume=False)), ("actor-0", chaos.actor_argv("actor-0"))]:
        assert argv[:4] == ["ip", "netns", "exec", chaos.network.namespace[ident]]
        args = build_parser().parse_args(argv[argv.index("ennc_ql.cli") + 1 :])
        conf = config_from_args(args)
        assert json.loads(conf.get_json("connect/endpoints")) == [f"{scheme}/{router}:{chaos.links[ident]}"]
        assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
        assert json.loads(conf.get_json("mode")) == "client"
    router_argv = chaos.router_argv()
    assert router_argv[:4] == ["ip", "netns", "exec", chaos.network.namespace["router"]]
    conf = config_from_args(
        build_parser(router_only=True).parse_args(router_argv[router_argv.index("ennc_ql.cli") + 1 :])
    )
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    if secure:
        cert = x509.load_pem_x509_certificate((tmp_path / "secure" / "router.pem").read_bytes())
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert router in [str(a) for a in names.get_values_for_type(x509.IPAddress)]


def test_without_namespaces_the_network_faults_are_skipped_saying_why(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from ennc_ql import chaos as command
    from tools.chaos import ChaosOptions

    why = "cannot create network namespaces (needs root)"
    monkeypatch.setattr(command, "unavailable", lambda: why)
    mixed = ChaosOptions(60.0, True, 5.0, ("learner-kill", "partition", "delay", "oversize"), 5.0)
    options, skipped = command.without_unavailable_network(mixed)
    assert options.faults == ("learner-kill", "oversize")
    assert skipped == dict.fromkeys(("partition", "delay"), why)
    assert capsys.readouterr().err == ""  # said by chaos once every argument is checked (tests/ennc_ql/test_bad_input)
    with pytest.raises(SystemExit) as exited:
        command.without_unavailable_network(ChaosOptions(60.0, True, 5.0, ("loss",), 5.0))
    assert exited.value.code == 2
    assert capsys.readouterr().err == f"ennc-ql chaos: error: --faults: network namespaces are needed for loss: {why}\n"
