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

import datetime
import ipaddress
import json
import logging
import os
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from protocol.keys import KeySpace
from protocol.security import OBSERVER, ROUTER, TlsFiles, access_control, client_config, router_config

log = logging.getLogger(__name__)

DEFAULT_HOSTS = ("localhost", "127.0.0.1")
"""Names and addresses the router's certificate is valid for, besides those given with ``--host``."""

VALID_DAYS = 365
CA_FILE, CA_KEY_FILE, CREDENTIALS_FILE = "ca.pem", "ca.key", "credentials.txt"
_SECRET, _PUBLIC, _FOLDER = 0o600, 0o644, 0o700


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


def _write(path: Path, data: bytes, mode: int) -> None:
    # Created with its final mode: a key is never readable by others, not even between open and chmod.
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    try:
        os.write(fd, data)
    finally:
        os.close(fd)
    os.chmod(path, mode)


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _name(common_name: str) -> x509.Name:
    return x509.Name(
        [x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ennc-ql"), x509.NameAttribute(NameOID.COMMON_NAME, common_name)]
    )


def _builder(subject: x509.Name, issuer: x509.Name, public_key: Any) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.UTC)
    return (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(issuer)
        .public_key(public_key)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))  # clocks of other machines may lag a little
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
    )


def _load_or_make_ca(folder: Path) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    cert_path, key_path = folder / CA_FILE, folder / CA_KEY_FILE
    if cert_path.exists() and key_path.exists():
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise ValueError(f"{key_path} is not an EC private key written by ennc-ql secure init")
        return key, x509.load_pem_x509_certificate(cert_path.read_bytes())
    key = _key()
    name = _name("ennc-ql CA")
    cert = (
        _builder(name, name, key.public_key())
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )  # key_cert_sign and crl_sign only
        .sign(key, hashes.SHA256())
    )
    _write(key_path, _pem_key(key), _SECRET)
    _write(cert_path, cert.public_bytes(serialization.Encoding.PEM), _PUBLIC)
    return key, cert


def _alt_names(hosts: Sequence[str]) -> list[x509.GeneralName]:
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return names


def _leaf(
    ca_key: ec.EllipticCurvePrivateKey, ca: x509.Certificate, ident: str, hosts: Sequence[str], server: bool
) -> tuple[bytes, bytes]:
    key = _key()
    usage = [ExtendedKeyUsageOID.SERVER_AUTH] if server else [ExtendedKeyUsageOID.CLIENT_AUTH]
    cert = (
        _builder(_name(ident), ca.subject, key.public_key())
        # A leaf: zenoh's TLS (rustls) refuses a CA certificate presented as an end entity.
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(_alt_names(hosts)), critical=False)
        .add_extension(x509.ExtendedKeyUsage(usage), critical=False)
        .sign(ca_key, hashes.SHA256())
    )
    return cert.public_bytes(serialization.Encoding.PEM), _pem_key(key)


def write_secure_set(spec: SecureSet) -> list[str]:
    """Write (or refresh) the CA, certificates, keys, credentials and configurations of ``spec``; return the names
    of the files written. Existing CA files are reused; every identity gets a fresh key and
    password, so re-running it revokes nothing but replaces everything else."""
    folder = spec.folder
    folder.mkdir(parents=True, exist_ok=True)
    os.chmod(folder, _FOLDER)
    mount = spec.mount or folder.resolve()
    ca_key, ca = _load_or_make_ca(folder)
    passwords = {ident: secrets.token_urlsafe(24) for ident in (ROUTER, *spec.identities)}
    for ident in (ROUTER, *spec.identities):
        hosts = (*DEFAULT_HOSTS, *spec.hosts) if ident == ROUTER else (ident,)
        cert, key = _leaf(ca_key, ca, ident, list(dict.fromkeys(hosts)), server=ident == ROUTER)
        _write(folder / f"{ident}.pem", cert, _PUBLIC)
        _write(folder / f"{ident}.key", key, _SECRET)
    # The router's dictionary: the users it accepts (its own password only serves the other direction).
    lines = "".join(f"{ident}:{passwords[ident]}\n" for ident in spec.identities)
    _write(folder / CREDENTIALS_FILE, lines.encode(), _SECRET)

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
        _write(spec.config(ident), (header + json.dumps(conf, indent=2) + "\n").encode(), _SECRET)
    written = [CA_FILE, CA_KEY_FILE, CREDENTIALS_FILE]
    written += [f"{i}{ext}" for i in (ROUTER, *spec.identities) for ext in (".pem", ".key", ".json5")]
    log.info("secure set for %s written into %s (%d files)", ", ".join(spec.identities), folder, len(written))
    return written
