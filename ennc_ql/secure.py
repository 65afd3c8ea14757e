"""``ennc-ql secure init DIR``: everything a secure run needs, written once into one folder
(:mod:`tools.secure` writes it)::

    ennc-ql secure init secrets --actors 2 --host 10.0.0.5        # the router's address, as clients dial it
    ennc-ql router  --zenoh-config secrets/router.json5
    ennc-ql learner --zenoh-config secrets/learner.json5 ...
    ennc-ql actor   --zenoh-config secrets/actor-0.json5 --actor-id actor-0 ...
"""

from __future__ import annotations

import argparse
import ipaddress
import re
from pathlib import Path
from typing import Any

from ennc_ql.command import check_folder, fail
from ennc_ql.parser import CommandHelp, add_command, add_commands, say
from protocol import check_id
from protocol.keys import KeySpace
from protocol.security import OBSERVER, ROUTER
from tools.config import folder, positive
from tools.secure import CA_FILE, CA_KEY_FILE, CREDENTIALS_FILE, DEFAULT_HOSTS, SecureSet, write_secure_set

_HOST = re.compile(r"[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*")

MAX_IDENTITIES = 10_000
"""The most actor identities one ``secure init`` writes (four files each): far beyond a cluster's actors, short of a
mistyped count that fills the disk."""


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
    say(f"wrote {len(written)} files into {spec.folder} (keys and configurations 0600):")
    for ident in (ROUTER, *spec.identities):
        say(f"  {ident:<10} --zenoh-config {spec.mount or spec.folder}/{ident}.json5")
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
    init.add_argument(
        "--actors",
        type=positive(int, most=MAX_IDENTITIES, why=" (each a key, a certificate, a password and a configuration)"),
        default=2,
        help=f"actor identities actor-0, actor-1, ... (at most {MAX_IDENTITIES})",
    )
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
