"""What every command shares: the one-line error, a configuration from its file and flags, a checked run folder,
the result printed as a table or as one JSON object, and the flags and Zenoh session of a process command."""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any, NoReturn

import zenoh

from ennc_ql.config import ConfigError, add_config_flags, load_config
from monitor import add_rerun_args
from protocol import ZenohTransport, add_connection_args, config_from_args, keys_from_args


def fail(command: str, message: str) -> NoReturn:
    """A one-line error on stderr and exit status 2, as argparse does for a bad flag."""
    print(f"ennc-ql {command}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def emit(result: dict[str, Any], as_json: bool, table: str) -> None:
    """The command's result: ``table`` for a person, or exactly one JSON object (``--json``)."""
    print(json.dumps(result) if as_json else table)


def configure(cls: type[Any], args: argparse.Namespace, command: str, defaults: dict[str, Any] | None = None) -> Any:
    """The command's configuration from its ``--config`` file and flags, or a one-line error naming what is wrong."""
    try:
        return load_config(cls, file=args.config, args=args, defaults=defaults)
    except ConfigError as exc:
        fail(command, str(exc))
    except OSError as exc:
        fail(command, f"--config {args.config}: {exc.strerror or exc}")


def writable_dir(path: Path, command: str, flag: str) -> Path:
    """``path`` created if needed and checked writable now, before any process state exists."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as exc:
        fail(command, f"{flag} {path}: not a writable folder ({exc.strerror or exc})")
    return path


def add_process_args(p: argparse.ArgumentParser, cls: type[Any], title: str) -> None:
    """The flags of a process command (``learner``, ``actor``): its configuration's, the Zenoh and the Rerun ones."""
    p.add_argument("--config", metavar="FILE", help="TOML file with the configuration fields; flags given override it")
    p.add_argument("--json", action="store_true", help="print the final result as one JSON object")
    add_config_flags(p.add_argument_group(title), cls)
    add_connection_args(p)
    add_rerun_args(p)


def open_transport(args: argparse.Namespace, command: str, ident: str) -> ZenohTransport:
    """The process's Zenoh session from the shared connection flags, or a one-line error."""
    try:
        conf = config_from_args(args)
    except (ValueError, OSError, zenoh.ZError) as exc:
        fail(command, f"zenoh configuration: {exc}")
    # With credentials, the router's access control lets this process publish only under its user name: any other
    # id would have every message dropped in silence, and its outbox would never drain.
    user = json.loads(conf.get_json("transport/auth/usrpwd/user"))
    if user is not None and user != ident:
        fail(command, f"the zenoh configuration authenticates as {user!r} but this process's id is {ident!r}")
    return ZenohTransport.open(conf, keys_from_args(args))
