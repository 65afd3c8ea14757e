"""How every process of a run joins it: peer-to-peer on the learner's listener, or through a router, plain or with
mutual TLS, a password and an access-control identity per process (``ennc-ql secure init``'s files in
``RUN/secure``); on loopback (``up``, ``chaos``) or on the address of a SLURM job's first node (``ennc-ql slurm``).
They all start their children with these flags::

    ends = make_endpoints(run_dir, "run-x", "learner", ["actor-0", "actor-1"], router=True, secure=True)
    ennc_ql_argv("router", *ends.router_flags())
    ennc_ql_argv("actor", "--config", ..., *ends.flags("actor-0"))
    with ZenohTransport.open(ends.session(OBSERVER), KeySpace("run-x")) as transport: ...   # a session of our own
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from protocol import zenoh_config
from protocol.security import ROUTER
from tools.secure import DEFAULT_HOSTS, SecureSet, write_secure_set
from tools.system import free_port

LOOPBACK = "127.0.0.1"


def _tls_name(host: str) -> str:
    """What a TLS client dials: on loopback the name the router's certificate holds, else the address itself."""
    return "localhost" if host == LOOPBACK else host


@dataclass(frozen=True, slots=True)
class Endpoints:
    port: int
    """The port the learner (peer-to-peer) or the router listens on."""
    namespace: str
    learner_id: str
    router: bool
    """Through a router (every process its client) rather than peer-to-peer on the learner's listener."""
    secure: SecureSet | None
    """The identities' files (None: plain TCP, nobody authenticated); a secure run goes through a router."""
    host: str = LOOPBACK
    """The address the listener binds and the others dial."""

    @property
    def endpoint(self) -> str:
        """The endpoint as the reports show it, and as clients dial it."""
        return f"tls/{_tls_name(self.host)}:{self.port}" if self.secure else f"tcp/{self.host}:{self.port}"

    def router_flags(self) -> list[str]:
        if self.secure:
            return ["--zenoh-config", str(self.secure.config(ROUTER))]
        return ["--listen", f"tcp/{self.host}:{self.port}"]

    def flags(self, ident: str) -> list[str]:
        """The zenoh flags of the learner or an actor (by id)."""
        common = ["--namespace", self.namespace, "--no-multicast-scouting"]
        if self.secure:
            return ["--zenoh-config", str(self.secure.config(ident)), *common]
        if self.router:
            return ["--connect", self.endpoint, "--mode", "client", *common]
        return ["--listen" if ident == self.learner_id else "--connect", self.endpoint, *common]

    def session(self, ident: str) -> zenoh.Config:
        """The configuration of a session of our own as ``ident`` (the observer; any id when plain)."""
        if self.secure:
            return zenoh_config(config_file=str(self.secure.config(ident)))
        return zenoh_config(connect=[self.endpoint], mode="client" if self.router else "peer")

    def client_dict(self, ident: str) -> dict[str, Any]:
        """``ident``'s zenoh configuration as a dict, to derive broken ones from (secure runs only)."""
        assert self.secure is not None
        text = self.secure.config(ident).read_text()
        # write_secure_set writes a comment line, then plain JSON.
        conf: dict[str, Any] = json.loads("\n".join(ln for ln in text.splitlines() if not ln.startswith("//")))
        return conf


def make_endpoints(
    run_dir: Path,
    namespace: str,
    learner_id: str,
    actor_ids: list[str],
    *,
    router: bool,
    secure: bool,
    others: tuple[str, ...] = (),
    host: str = LOOPBACK,
    hosts: tuple[str, ...] = (),
) -> Endpoints:
    """A port free on ``host`` now (this machine is where the listener will run) and, ``secure``, every identity's
    files in ``run_dir/secure``: the learner's, the actors', the router's, the observer's and ``others`` (identities
    of sessions of our own); the router's certificate is valid for loopback, ``host`` and ``hosts`` (other names or
    addresses clients dial)."""
    port = free_port(host)
    if not secure:
        return Endpoints(port, namespace, learner_id, router, None, host)
    spec = SecureSet(
        folder=run_dir / "secure",
        actor_ids=(*actor_ids, *others),
        learner_id=learner_id,
        namespace=namespace,
        hosts=(*DEFAULT_HOSTS, host, *hosts),
        listen=(f"tls/{host}:{port}",),
        connect=(f"tls/{_tls_name(host)}:{port}",),
    )
    write_secure_set(spec)
    return Endpoints(port, namespace, learner_id, True, spec, host)
