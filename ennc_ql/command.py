"""What every command shares: the one-line error, a configuration from its file and flags, folders checked before
anything is created, the result printed as a table or as one JSON object, and the flags and Zenoh session of a
process command. Everything here is light to import: the router's process loads it, and never the simulator."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
import tempfile
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any, NoReturn

import zenoh

from ennc_ql.parser import say
from monitor import Sink, add_rerun_args
from monitor.sinks import serve_problem, spawn_problem
from protocol import ZenohTransport, add_connection_args, config_from_args, keys_from_args
from tools.config import ConfigError, add_config_flags, file_path, load_config, too_long
from tools.config_fields import UnknownKey, nested_fields

_RUST_SOURCE = re.compile(r"\s+at /\S+\.rs:\d+\.?")
_JSON_ERROR = re.compile(
    r'JSON error: Message \{ msg: "(.*)", location: Some\(Location \{ line: (\d+), column: (\d+) \}\) \}'
)
_PORTED = ("tcp", "udp", "tls", "quic", "ws")


def fail(command: str, message: str) -> NoReturn:
    """A one-line error on stderr and exit status 2, as argparse does for a bad flag."""
    print(f"ennc-ql {command}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def emit(result: dict[str, Any], as_json: bool, table: str) -> None:
    """The command's result: ``table`` for a person, or exactly one JSON object (``--json``)."""
    say(json.dumps(result) if as_json else table)


def configure(cls: type[Any], args: argparse.Namespace, command: str, defaults: dict[str, Any] | None = None) -> Any:
    """The command's configuration from its ``--config`` file and flags, or a one-line error naming what is wrong."""
    try:
        return load_config(cls, file=args.config, args=args, defaults=defaults)
    except UnknownKey as exc:
        fail(command, wrong_role(cls, Path(args.config), exc))
    except ConfigError as exc:
        fail(command, str(exc))
    except OSError as exc:
        fail(command, f"--config {args.config}: {exc.strerror or exc}")


def _roles() -> dict[str, tuple[type[Any], str]]:
    """Each process's configuration class, with where its settings go."""
    # Imported here: the router's process never loads the simulator, which these configurations import.
    from actors.config import ActorConfig
    from learner.config import LearnerConfig
    from tools.cluster import UpConfig

    return {
        "up": (UpConfig, "ennc-ql up --config and slurm train --config take it"),
        "learner": (LearnerConfig, "ennc-ql learner --config takes it; in up's file it is the [learner] table"),
        "actor": (ActorConfig, "ennc-ql actor --config takes it; in up's file it is the [actor] table"),
    }


_OWNER = {"up": "up's", "learner": "a learner's", "actor": "an actor's"}


def wrong_role(cls: type[Any], file: Path, exc: UnknownKey) -> str:
    """The message for a key of ``file`` that ``cls`` lacks: the file is another process's configuration, or the key
    is another process's setting; else the error as it is."""
    roles = _roles()
    mine = next((role for role, (klass, _) in roles.items() if klass is cls), None)
    if mine is None:
        return str(exc)
    for role, (klass, where) in roles.items():
        if klass is cls:
            continue
        try:
            load_config(klass, file=file)
        except ConfigError:
            continue
        return f"{file} is {_OWNER[role]} configuration file ({where}), not {_OWNER[mine]}"
    top = exc.path.split(".")[0]
    for role, (klass, _) in roles.items():
        if klass is not cls and role != "up" and top in {f.name for f in dataclasses.fields(klass)}:
            table = f"[{role}.{top}]" if top in nested_fields(klass) else f"{role}.{top} in [{role}]"
            owners = f"{_OWNER[role]} setting, not {_OWNER[mine]}"
            return f"{file}: unknown key {exc.path!r}: {top} is {owners} (in up's configuration: {table})"
    return str(exc)


def check_file(path: str, command: str, flag: str) -> None:
    """Fail unless ``path`` names a file that exists (not a folder)."""
    if not path.strip():
        fail(command, f"{flag}: expected a file, got an empty value")
    problem = too_long(path)
    if problem:
        fail(command, f"{flag}: {problem}")
    if os.path.isdir(path):
        fail(command, f"{flag} {path}: a folder, not a file")
    if not os.path.isfile(path):
        fail(command, f"{flag} {path}: no such file")


def check_folder(path: Path, command: str, flag: str, *, empty: bool = False) -> None:
    """Fail unless ``path`` is a folder, or could be created as one, where this process can write; with ``empty``,
    also if it holds anything. Creates nothing: a check that fails must leave nothing behind."""
    if path.exists() and not path.is_dir():
        fail(command, f"{flag} {path}: a file is in the way of the folder")
    if empty and path.is_dir() and any(path.iterdir()):
        fail(command, f"{flag} {path}: the folder is not empty (another run's files would be taken for this one's)")
    base = path
    while not base.exists():
        base = base.parent
    if not base.is_dir():
        fail(command, f"{flag} {path}: {base} is a file, not a folder")
    try:  # the one way to know, whoever the user is: a file created and removed at once
        with tempfile.NamedTemporaryFile(dir=base, prefix=".ennc-ql-write-test-"):
            pass
    except OSError as exc:
        fail(command, f"{flag} {path}: cannot write in {base} ({exc.strerror or exc})")


TRAINED = ("checkpoint.npz", "report.json", "policy.npz")
"""What a learner leaves in its run folder: a folder holding one of them holds a run that trained, finished or
interrupted."""
RUN_FILES = (*TRAINED, "job.sh", "results.json")
"""What a training or sweep command leaves in its folder (``slurm train``'s job script, a sweep's results besides a
learner's files): a folder holding one of them holds a run that a command must not write over unless it resumes
that run."""


def run_files(path: Path, names: Collection[str] = RUN_FILES) -> list[str]:
    """The files of ``names`` in folder ``path`` (none where it is missing)."""
    return [name for name in names if (path / name).exists()]


def refuse_run(
    path: Path,
    command: str,
    named: str,
    resume: str | None,
    *,
    another: str = "give another folder",
    names: Collection[str] = RUN_FILES,
) -> None:
    """Fail if folder ``path`` holds a run (:data:`RUN_FILES`): its checkpoint, report and policy are the user's data,
    and only a resume may add to them. ``named`` names the folder in the message (the flag that gave it), ``resume``
    says how this command continues that run (None: it cannot), ``another`` how the user chooses another folder with
    this command's flags; ``names``: the files that make a run for this command."""
    held = run_files(path, names)
    if held:
        advice = another if resume is None else f"continue it with {resume}, or {another}"
        fail(command, f"{named} holds a run already ({', '.join(held)}), which this would overwrite: {advice}")


def make_folder(path: Path, command: str, flag: str) -> Path:
    """``path`` created (with its parents) once every check has passed."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        fail(command, f"{flag} {path}: cannot create the folder ({exc.strerror or exc})")
    return path


def writable_dir(path: Path, command: str, flag: str) -> Path:
    """``path`` checked writable, then created if needed."""
    check_folder(path, command, flag)
    return make_folder(path, command, flag)


def check_recording(sink: Sink | None, command: str, *, resuming: bool = False) -> None:
    """A ``--rerun save PATH`` whose file cannot be written, or that lies in another run's folder (unless the command
    resumes that run), or a ``--rerun spawn`` without a viewer or a display, fails now, not once the processes
    started; so does a ``--rerun learner`` given to another command than ``actor``."""
    if sink is not None and sink.kind == "learner" and command != "actor":
        fail(
            command,
            "--rerun learner: only an actor relays its rows to the learner; choose off, save, spawn, connect or serve",
        )
    if sink is not None and sink.kind == "serve":
        problem = serve_problem()
        if problem:
            fail(command, f"--rerun serve: {problem}")
    if sink is not None and sink.kind == "spawn":
        problem = spawn_problem()
        if problem:
            fail(command, f"--rerun spawn: {problem}")
    if sink is None or sink.kind != "save":
        return
    problem = too_long(str(sink.target))
    if problem:
        fail(command, f"--rerun save: {problem}")
    target = Path(str(sink.target))
    if target.is_dir():
        fail(command, f"--rerun save {target}: a folder, not a file (give e.g. {target / 'run.rrd'})")
    check_folder(target.parent, command, "--rerun save")
    if not resuming:
        refuse_run(target.parent, command, f"--rerun save {target}: its folder", None)


def check_device(device: str, command: str, flag: str) -> None:
    """A torch device that this machine has: a learner given another would fail at its first fit, minutes in."""
    if device == "cpu":
        return
    import torch  # only for a device other than the CPU

    try:
        kind = torch.device(device)
    except (RuntimeError, ValueError):
        fail(command, f"{flag} {device}: not a torch device (e.g. cpu, cuda, cuda:0)")
    if kind.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            fail(command, f"{flag} {device}: this machine has no CUDA device (or torch was built without CUDA)")
        if kind.index is not None and kind.index >= count:
            fail(command, f"{flag} {device}: this machine has {count} CUDA device(s), cuda:0 to cuda:{count - 1}")
    elif kind.type != "cpu":
        fail(command, f"{flag} {device}: only cpu and cuda devices are supported")


def registry_choices() -> dict[str, Collection[str]]:
    """The values of configuration fields that name an entry of a registry, by field name: their flags offer
    exactly these."""
    from sim import SCENARIOS  # imported here: the router's process never loads the simulator
    from sim.actions import ACTION_SETS
    from sim.features import FEATURIZER_REGISTRY
    from sim.formulation import FORMULATIONS, REWARD_NAMES, TRIAL_RULES

    return {
        "formulation": FORMULATIONS,
        "featurizer": FEATURIZER_REGISTRY,
        "reward": REWARD_NAMES,
        "actions": ACTION_SETS,
        "trial_rules": TRIAL_RULES,
        "scenario": SCENARIOS,
    }


def zenoh_message(exc: BaseException) -> str:
    """Zenoh's error as one line for a user: without Rust source paths, and with JSON5 parse errors located."""
    text = _RUST_SOURCE.sub("", str(exc)).strip()
    json_error = _JSON_ERROR.search(text)
    if json_error:
        msg, line, column = json_error.groups()
        return f"{msg.replace(chr(96), chr(39))} (line {line}, column {column})"
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if lines and lines[0].startswith("-->"):  # the JSON5 parser's caret diagram: its position and its last line
        where = lines[0].removeprefix("-->").strip().split(":")
        what = lines[-1].lstrip("= ").strip()
        return f"not valid JSON5: {what} (line {where[0]}, column {where[-1]})"
    return " ".join(lines)


def check_endpoints(args: argparse.Namespace, command: str) -> None:
    """``--connect``/``--listen`` endpoints that zenoh would only refuse once a session opens (or never, retrying
    a port that cannot exist)."""
    for flag, endpoints in (("--connect", args.connect), ("--listen", args.listen)):
        for endpoint in endpoints:
            proto, sep, address = endpoint.partition("/")
            if not sep or not proto or not address:
                fail(command, f"{flag} {endpoint}: expected PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447")
            if proto in _PORTED:
                port = re.split(r"[?#]", address)[0].rpartition(":")[2]  # endpoints may carry ?metadata#config
                lowest = 0 if flag == "--listen" else 1  # listening on port 0 takes any free one
                if not port.isdigit() or not lowest <= int(port) <= 65535:
                    fail(command, f"{flag} {endpoint}: expected HOST:PORT with a port from {lowest} to 65535")


def zenoh_conf(args: argparse.Namespace, command: str) -> zenoh.Config:
    """The Zenoh configuration the shared connection flags select, or a one-line error."""
    check_endpoints(args, command)
    if args.zenoh_config is not None:
        check_file(args.zenoh_config, command, "--zenoh-config")
    try:
        return config_from_args(args)
    except (ValueError, OSError, zenoh.ZError) as exc:
        where = f"--zenoh-config {args.zenoh_config}" if args.zenoh_config else "zenoh configuration"
        fail(command, f"{where}: {zenoh_message(exc)}")


def add_process_args(
    p: argparse.ArgumentParser, cls: type[Any], title: str, choices: Mapping[str, Collection[str]]
) -> None:
    """The flags of a process command (``learner``, ``actor``): its configuration's, the Zenoh and the Rerun ones."""
    p.add_argument(
        "--config",
        type=file_path,
        metavar="FILE",
        help="TOML file with the configuration fields; flags given override it (default: none)",
    )
    p.add_argument("--json", action="store_true", help="print the final result as one JSON object")
    add_config_flags(p.add_argument_group(title), cls, choices=choices)
    add_connection_args(p)
    add_rerun_args(p, relay=cls.__name__ == "ActorConfig")


def checked_zenoh(args: argparse.Namespace, command: str, ident: str) -> zenoh.Config:
    """The process's Zenoh configuration, checked before anything starts: it parses, and a configuration with
    credentials authenticates as this process."""
    conf = zenoh_conf(args, command)
    # With credentials, the router's access control lets this process publish only under its user name: any other
    # id would have every message dropped in silence, and its outbox would never drain.
    user = json.loads(conf.get_json("transport/auth/usrpwd/user"))
    if user is not None and user != ident:
        fail(command, f"the zenoh configuration authenticates as {user!r} but this process's id is {ident!r}")
    return conf


def open_transport(conf: zenoh.Config, args: argparse.Namespace, command: str) -> ZenohTransport:
    """The process's Zenoh session, or a one-line error (an address in use, a protocol zenoh does not have)."""
    try:
        return ZenohTransport.open(conf, keys_from_args(args))
    except zenoh.ZError as exc:
        fail(command, f"zenoh could not open a session: {zenoh_message(exc)}")
