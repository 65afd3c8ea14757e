"""How every process of a local run joins it: peer-to-peer on the learner's loopback listener, or through a router,
plain or with mutual TLS, a password and an access-control identity per process (``ennc-ql secure init``'s files in
``RUN/secure``). ``up`` and ``chaos`` both start their children with these flags::

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

from ennc_ql.secure import DEFAULT_HOSTS, SecureSet, write_secure_set
from ennc_ql.system import free_port
from protocol import zenoh_config
from protocol.security import ROUTER


@dataclass(frozen=True, slots=True)
class Endpoints:
    port: int
    """The loopback port the learner (peer-to-peer) or the router listens on."""
    namespace: str
    learner_id: str
    router: bool
    """Through a router (every process its client) rather than peer-to-peer on the learner's listener."""
    secure: SecureSet | None
    """The identities' files (None: plain TCP, nobody authenticated); a secure run goes through a router."""

    @property
    def endpoint(self) -> str:
        """The endpoint as the reports show it, and as clients dial it."""
        return f"tls/localhost:{self.port}" if self.secure else f"tcp/127.0.0.1:{self.port}"

    def router_flags(self) -> list[str]:
        if self.secure:
            return ["--zenoh-config", str(self.secure.config(ROUTER))]
        return ["--listen", f"tcp/127.0.0.1:{self.port}"]

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
    hosts: tuple[str, ...] = (),
) -> Endpoints:
    """A free loopback port and, ``secure``, every identity's files in ``run_dir/secure``: the learner's, the actors',
    the router's, the observer's and ``others`` (identities of sessions of our own); the router's certificate is
    valid for loopback and ``hosts`` (other names or addresses clients dial)."""
    port = free_port()
    if not secure:
        return Endpoints(port, namespace, learner_id, router, None)
    spec = SecureSet(
        folder=run_dir / "secure",
        actor_ids=(*actor_ids, *others),
        learner_id=learner_id,
        namespace=namespace,
        hosts=(*DEFAULT_HOSTS, *hosts),
        listen=(f"tls/127.0.0.1:{port}",),
        connect=(f"tls/localhost:{port}",),
    )
    write_secure_set(spec)
    return Endpoints(port, namespace, learner_id, True, spec)
