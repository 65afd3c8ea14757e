"""Everything a secure run needs, written once into one folder (``ennc-ql secure init`` is its command).

A certificate authority, a certificate and key per identity (the router, the learner, every actor, the observer
that read-only tools use), a password per identity with the router's credential file, and one zenoh JSON5
configuration per process whose access-control rules are those of ``protocol.security``::

    written = write_secure_set(SecureSet(Path("secrets"), actor_ids=("actor-0", "actor-1"), hosts=("10.0.0.5",)))
    # ennc-ql router --zenoh-config secrets/router.json5; ennc-ql learner --zenoh-config secrets/learner.json5 ...

Private keys, passwords and the configurations that hold passwords are written 0600 (the folder 0700);
certificates 0644. Nothing secret is ever logged. The CA's key is kept in the folder (0600) so that the set can be
written again with more actors; move it offline once the set is final.

Paths inside the configurations are those of ``mount`` (default: the folder itself), so a set generated on one
machine can be mounted elsewhere, e.g. as Docker secrets under ``/run/secrets/enncql``.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocol.keys import KeySpace
from protocol.security import OBSERVER, ROUTER, TlsFiles, access_control, client_config, router_config

log = logging.getLogger(__name__)

DEFAULT_HOSTS = ("localhost", "127.0.0.1")
"""Names and addresses the router's certificate is valid for, besides those given with ``--host``."""

CA_FILE, CA_KEY_FILE, CREDENTIALS_FILE = "ca.pem", "ca.key", "credentials.txt"
_FOLDER = 0o700


@dataclass(frozen=True, slots=True)
class SecureSet:
    """What ``secure init`` writes: the folder, the identities and the endpoints their configurations use."""

    folder: Path
    actor_ids: tuple[str, ...]
    learner_id: str = "learner"
    namespace: str = ""
    hosts: tuple[str, ...] = DEFAULT_HOSTS
    listen: tuple[str, ...] = ("tls/0.0.0.0:7447",)
    connect: tuple[str, ...] = ("tls/localhost:7447",)
    mount: Path | None = None
    """Where the folder will be seen by the processes (paths inside the configurations); default: ``folder``."""

    def config(self, ident: str) -> Path:
        """The zenoh configuration file of ``ident`` (``router``, the learner id, an actor id or ``observer``)."""
        return self.folder / f"{ident}.json5"

    @property
    def identities(self) -> tuple[str, ...]:
        return (self.learner_id, *self.actor_ids, OBSERVER)


def write_secure_set(spec: SecureSet) -> list[str]:
    """Write (or refresh) the CA, certificates, keys, credentials and configurations of ``spec``; return the names
    of the files written. Existing CA files are reused; every identity gets a fresh key and
    password, so re-running it revokes nothing but replaces everything else."""
    # Imported here: a process that only reads a set's paths (every actor of a run) never maps cryptography's
    # libraries (9 MB resident).
    from tools.certificates import PUBLIC, SECRET, leaf, load_or_make_ca, write_file

    folder = spec.folder
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, _FOLDER)
    mount = spec.mount or folder.resolve()
    ca_key, ca = load_or_make_ca(folder, CA_FILE, CA_KEY_FILE)
    passwords = {ident: secrets.token_urlsafe(24) for ident in (ROUTER, *spec.identities)}
    for ident in (ROUTER, *spec.identities):
        hosts = (*DEFAULT_HOSTS, *spec.hosts) if ident == ROUTER else (ident,)
        cert, key = leaf(ca_key, ca, ident, list(dict.fromkeys(hosts)), server=ident == ROUTER)
        write_file(folder / f"{ident}.pem", cert, PUBLIC)
        write_file(folder / f"{ident}.key", key, SECRET)
    # The router's dictionary: the users it accepts (its own password only serves the other direction).
    lines = "".join(f"{ident}:{passwords[ident]}\n" for ident in spec.identities)
    write_file(folder / CREDENTIALS_FILE, lines.encode(), SECRET)

    def tls(ident: str) -> TlsFiles:
        return TlsFiles(str(mount / CA_FILE), str(mount / f"{ident}.pem"), str(mount / f"{ident}.key"))

    rules = access_control(KeySpace(spec.namespace), spec.learner_id, spec.actor_ids)
    configs: dict[str, dict[str, Any]] = {
        ROUTER: router_config(spec.listen, tls(ROUTER), str(mount / CREDENTIALS_FILE), passwords[ROUTER], rules)
    }
    for ident in spec.identities:
        configs[ident] = client_config(spec.connect, tls(ident), ident, passwords[ident])
    for ident, conf in configs.items():
        header = f"// zenoh configuration of {ident}, written by ennc-ql secure init; holds a password: keep it 0600.\n"
        write_file(spec.config(ident), (header + json.dumps(conf, indent=2) + "\n").encode(), SECRET)
    written = [CA_FILE, CA_KEY_FILE, CREDENTIALS_FILE]
    written += [f"{i}{ext}" for i in (ROUTER, *spec.identities) for ext in (".pem", ".key", ".json5")]
    log.info("secure set for %s written into %s (%d files)", ", ".join(spec.identities), folder, len(written))
    return written
