"""``ennc-ql secure init DIR``: everything a secure run needs, written once into one folder.

A certificate authority, a certificate and key per identity (the router, the learner, every actor, the observer
that read-only tools use), a password per identity with the router's credential file, and one zenoh JSON5
configuration per process whose access-control rules are those of ``protocol.security``::

    ennc-ql secure init secrets --actors 2 --host 10.0.0.5        # the router's address, as clients dial it
    ennc-ql router  --zenoh-config secrets/router.json5
    ennc-ql learner --zenoh-config secrets/learner.json5 ...
    ennc-ql actor   --zenoh-config secrets/actor-0.json5 --actor-id actor-0 ...

Private keys, passwords and the configurations that hold passwords are written 0600 (the folder 0700);
certificates 0644. Nothing secret is ever logged. The CA's key is kept in the folder (0600) so that
``ennc-ql secure init`` can be run again with more actors; move it offline once the set is final.

Paths inside the configurations are those of ``--mount`` (default: the folder itself), so a set generated on one
machine can be mounted elsewhere, e.g. as Docker secrets under ``/run/secrets/enncql``.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import json
import logging
import os
import re
import secrets
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from ennc_ql.command import check_folder, fail
from ennc_ql.config import folder, positive
from ennc_ql.parser import CommandHelp, add_command, add_commands
from protocol import check_id
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


_HOST = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*")


def _port(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port from 1 to 65535, got {text!r}")
    return int(text)


def _checked_spec(args: argparse.Namespace) -> SecureSet:
    """The set ``args`` asks for, every value checked before a file is written: a bad one fails, and nothing is
    left half-written."""
    for host in args.host:
        try:
            ipaddress.ip_address(host)
        except ValueError:
            if not _HOST.fullmatch(host):
                fail("secure init", f"--host {host}: not a host name or an IP address")
    actor_ids = tuple(f"actor-{i}" for i in range(args.actors))
    try:
        check_id(args.learner_id, "--learner-id")
        KeySpace(args.namespace)
    except ValueError as exc:
        fail("secure init", str(exc))
    if args.learner_id in (ROUTER, OBSERVER, *actor_ids):
        fail("secure init", f"--learner-id {args.learner_id}: already the id of another identity of the set")
    if args.mount is not None and not args.mount.is_absolute():
        fail("secure init", f"--mount {args.mount}: give an absolute path (the processes read it wherever they run)")
    hosts = tuple(args.host)
    return SecureSet(
        folder=args.dir,
        actor_ids=actor_ids,
        learner_id=args.learner_id,
        namespace=args.namespace,
        hosts=hosts or DEFAULT_HOSTS,
        listen=(f"tls/0.0.0.0:{args.port}",),
        connect=(f"tls/{hosts[0] if hosts else 'localhost'}:{args.port}",),
        mount=args.mount,
    )


def _ours(folder: Path) -> bool:
    """Whether ``folder`` holds a set written by ``secure init`` and nothing else (run again, it adds actors and
    replaces keys and passwords, keeping the CA)."""
    names = [p.name for p in folder.iterdir()]
    written = {CA_FILE, CA_KEY_FILE, CREDENTIALS_FILE}
    return CA_FILE in names and all(n in written or n.endswith((".pem", ".key", ".json5")) for n in names)


def cmd_secure_init(args: argparse.Namespace) -> int:
    spec = _checked_spec(args)
    check_folder(args.dir, "secure init", "DIR")
    if args.dir.is_dir() and any(args.dir.iterdir()) and not _ours(args.dir) and not args.force:
        fail("secure init", f"{args.dir}: the folder holds files secure init did not write; give --force to use it")
    try:
        written = write_secure_set(spec)
    except (OSError, ValueError) as exc:
        fail("secure init", str(exc))
    print(f"wrote {len(written)} files into {spec.folder} (keys and configurations 0600):")
    for ident in (ROUTER, *spec.identities):
        print(f"  {ident:<10} --zenoh-config {spec.mount or spec.folder}/{ident}.json5")
    return 0


SECURE = CommandHelp(
    "secure",
    "certificates, passwords and access control for secure runs over several machines",
    "Writes what a secure run needs (ennc-ql secure init DIR); see its own help: ennc-ql secure init --help.",
    (
        ("ennc-ql secure init secrets --actors 4 --host A.example.org", "a set for a router on A and 4 actors"),
        ("ennc-ql secure init --help", "what it writes, and where each file goes"),
    ),
    "under a second",
)

INIT = CommandHelp(
    "init",
    "write a CA, a certificate, key and password per process, and one Zenoh configuration per process",
    "Writes into DIR a certificate authority, a certificate, key and password per identity (the router, the "
    "learner, every actor, and the observer that read-only tools use), the router's credential file, and one Zenoh "
    "JSON5 configuration per process whose access control lets each actor publish only under its own key. Give "
    "each machine only its own files (ca.pem, ID.pem, ID.key, ID.json5); ca.key and credentials.txt stay with the "
    "router. Keys, passwords and configurations are written 0600, the folder 0700. Run it again on the same folder "
    "for more actors: the CA is kept, every key and password replaced. It refuses a folder that holds other files "
    "unless --force.",
    (
        ("ennc-ql secure init secrets --actors 4 --host A.example.org", "the router on A, 4 actors"),
        ("ennc-ql secure init secrets --mount /run/secrets/enncql", "files that containers mount elsewhere"),
    ),
    "under a second",
)


def add_secure_parser(sub: Any) -> None:
    p = add_command(sub, SECURE)
    init = add_command(add_commands(p, dest="secure_command"), INIT)
    init.add_argument("dir", type=folder, metavar="DIR", help="folder to write into (created 0700)")
    init.add_argument("--actors", type=positive(int), default=2, help="actor identities actor-0, actor-1, ...")
    init.add_argument(
        "--host",
        action="append",
        default=[],
        help="name or address of the router as clients dial it (repeatable; the first is the one they dial; "
        "default: localhost)",
    )
    init.add_argument("--port", type=_port, default=7447, help="the router's TLS port")
    init.add_argument("--learner-id", default="learner", help="the learner's id")
    init.add_argument(
        "--namespace", default="", help="the runs' --namespace: the rules cover its keys only (default: none)"
    )
    init.add_argument("--mount", type=Path, help="absolute path where the processes will see DIR (default: DIR)")
    init.add_argument("--force", action="store_true", help="write into a folder that holds other files")
    init.set_defaults(func=cmd_secure_init)
