"""One error contract for every command, through the console script: bad input gets one line,
``ennc-ql <command>: error: <what>``, at most one short usage line after it, exit status 2, and leaves nothing
behind (no run folder, no created directory, no recording), before anything starts.

Each row is a command line and the words its error must carry. Every row runs ``ennc-ql`` in a fresh working
folder that holds the fixtures below; the folder must hold exactly those afterwards.

The rows run twice (once with the optional programs hidden from PATH), 356 command lines: as new processes, each
would spend 0.7-3 s importing the command line, numba, zenoh and torch (314 s for 274 of them). They run instead in
forks of one process that imported the command line once (:mod:`tests.ennc_ql._forkserver`), each in its own session,
folder and environment, with the script's ``sys.argv``, entry point and exit status: ~0.12 s a row, most of it the
command's own parser (it reads its configurations' docstrings from their source). The tests at the end run the real
console script: three rows both ways, which must answer alike byte for byte, an ASCII terminal (an encoding a fork
can't change), a reader that goes away, an output that refuses what is written, a port in use."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from functools import partial
from importlib.metadata import entry_points
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from tests.ennc_ql._forkserver import ForkServer, text
from tools.config import dump_config

if TYPE_CHECKING:
    from tools.cluster import UpConfig

ENNC_QL = Path(sys.executable).with_name("ennc-ql")
PRELOAD = tuple(
    f"ennc_ql.{name}"
    for name in ("cli", "actor", "bench", "chaos", "evaluate", "learner", "router", "secure", "slurm", "sweeps", "up")
)
"""What the rows import: the command line and every command's module (numba, zenoh, msgpack come with them), 0.9 s.
Not torch, which the device checks import (3 rows, twice): it doubles the memory each fork copies, 0.03 s more a row,
more than its import costs those rows (1.2 s)."""
TIMEOUT_S = 90.0
"""A row that started something it should not have is stopped here (and fails): none takes a second to answer."""

LONG = "x" * 300
"""A file name longer than any file system's 255 bytes."""

ROWS: list[tuple[list[str], str]] = [
    # The command line itself.
    ([], "ennc-ql: error: which command? one of eval, up, learner,"),
    (["evl"], "ennc-ql: error: unknown command 'evl'; did you mean 'eval'?"),
    (["--frobnicate", "eval"], "ennc-ql: error: unknown option '--frobnicate'"),
    (["up", "--durtion", "5"], "ennc-ql up: error: unknown option '--durtion'; did you mean '--duration'?"),
    (["up", "--learner-learner-id", "x"], "ennc-ql up: error: unknown option '--learner-learner-id'; did you mean"),
    (["up", "--dur", "5"], "ennc-ql up: error: unknown option '--dur'"),
    (["learner", "--run-dir", "r", "--phase1-ncycles", "3"], "did you mean '--phase1-n-cycles'?"),
    (["eval", "extra"], "ennc-ql eval: error: unexpected argument 'extra'"),
    (["eval", "--trials"], "ennc-ql eval: error: --trials: needs a value"),
    # eval
    (["eval", "--seed", "-1"], "ennc-ql eval: error: --seed: expected an integer of 0 or more, got '-1'"),
    (["eval", "--trials", "0"], "ennc-ql eval: error: --trials: expected a positive integer of at most 100000"),
    (["eval", "--steps", "x"], "ennc-ql eval: error: --steps: expected a positive integer of at most 100000"),
    (["eval", "--scenario", "cmommt-v2"], "--scenario: unknown value 'cmommt-v2'; did you mean 'cmommt-v1'?"),
    (["eval", "--policy", "greedy"], "ennc-ql eval: error: --policy: unknown policy 'greedy' (one of random, local,"),
    (["eval", "--policy", "text.npz"], "--policy text.npz: not a policy file (not an .npz archive of plain arrays)"),
    (["eval", "--policy", "pickled.npy"], "--policy pickled.npy: not a policy file (not an .npz archive"),
    (["eval", "--policy", "run"], "ennc-ql eval: error: --policy run: a folder, not a policy file"),
    (["eval", "--policy", "run/checkpoint.npz"], "--policy run/checkpoint.npz: not a policy file (no header,"),
    (["eval", "--record-trial", "5", "--trials", "2"], "--record-trial 5: only trials 0 to 1 run (--trials)"),
    (["eval", "--rerun", "save", "/proc/x.rrd"], "ennc-ql eval: error: --rerun save /proc: cannot write in /proc"),
    (["eval", "--rerun", "save", "run"], "ennc-ql eval: error: --rerun save run: a folder, not a file"),
    (["eval", "--rerun", "bogus"], "ennc-ql eval: error: --rerun: unknown Rerun sink 'bogus'"),
    (["eval", "--rerun", "connect", "http://x"], "ennc-ql eval: error: --rerun: 'connect' needs a URL like"),
    (["eval", "--rerun", "learner"], "ennc-ql eval: error: --rerun learner: only an actor relays its rows to the"),
    (["learner", "--run-dir", "r", "--rerun", "learner"], "ennc-ql learner: error: --rerun learner: only an actor"),
    (["up", "--rerun", "learner"], "ennc-ql up: error: --rerun learner: only an actor relays its rows"),
    # up: everything it needs is checked before a process starts or a folder is made.
    (["up", "--learner-phase1-device", "cuda:7"], "ennc-ql up: error: --learner-phase1-device cuda:7: this machine"),
    (["up", "--learner-phase1-device", "tpu"], "--learner-phase1-device tpu: not a torch device"),
    (["up", "--rerun", "save", "/proc/x.rrd"], "ennc-ql up: error: --rerun save /proc: cannot write in /proc"),
    (["up", "--serial", "--secure"], "ennc-ql up: error: --serial runs on the in-memory bus"),
    (["up", "--seed", "-1"], "ennc-ql up: error: seed must be at least 0, got -1"),
    (["up", "--actors", "0"], "ennc-ql up: error: actors must be at least 1, got 0"),
    (["up", "--duration", "-5"], "ennc-ql up: error: duration must be positive, got -5.0"),
    (["up", "--actor-arenas", "-5"], "ennc-ql up: error: actor: arenas must be at least 1, got -5"),
    (["up", "--actor-learn", "5-2"], "ennc-ql up: error: --actor-learn: bad robot range"),
    (["up", "--formulation", "best"], "--formulation: unknown value 'best' (one of "),
    (
        ["up", "--learner-phase1-quantizer", "median"],
        "--learner-phase1-quantizer: unknown value 'median' (one of quantile, uniform)",
    ),
    (["up", "--run-id", "a/b"], "ennc-ql up: error: --run-id: 'a/b' is not"),
    (["up", "--runs", "/proc/x"], "ennc-ql up: error: --runs /proc/x/"),
    (["up", "--runs", "notes.txt"], "ennc-ql up: error: --runs notes.txt/"),
    (["up", "--runs", "used", "--run-id", "x"], "ennc-ql up: error: --runs used/x: the folder is not empty"),
    (["up", "--config", "missing.toml"], "ennc-ql up: error: cannot read config file 'missing.toml'"),
    (["up", "--config", "unknown.toml"], "ennc-ql up: error: unknown.toml: unknown key 'duraton' (did you mean"),
    # learner: a resume from the wrong folder creates nothing and opens no session.
    (["learner"], "ennc-ql learner: error: missing --run-dir"),
    (["learner", "--run-dir", "typo", "--resume"], "ennc-ql learner: error: --resume: no folder typo"),
    (["learner", "--run-dir", "empty", "--resume"], "ennc-ql learner: error: --resume: no checkpoint in empty"),
    (["learner", "--run-dir", "used", "--resume"], "--resume: used/checkpoint.npz is not a checkpoint"),
    (["learner", "--run-dir", "r", "--zenoh-config", "bad.json5"], "--zenoh-config bad.json5: not valid JSON5"),
    (["learner", "--run-dir", "r", "--zenoh-config", "unknown.json5"], "unknown field 'foo', expected one of"),
    (["learner", "--run-dir", "r", "--zenoh-config", "missing.json5"], "--zenoh-config missing.json5: no such file"),
    (["learner", "--run-dir", "r", "--connect", "tcp/1.2.3.4:99999"], "expected HOST:PORT with a port from 1 to"),
    (["learner", "--run-dir", "r", "--listen", "nowhere"], "--listen nowhere: expected PROTOCOL/ADDRESS"),
    (["learner", "--run-dir", "r", "--featurizer", "raw"], "--featurizer: unknown value 'raw' (one of local2d,"),
    (["learner", "--run-dir", "r", "--phase1-n-cycles", "0"], "ennc-ql learner: error: phase1: n_cycles"),
    (["learner", "--run-dir", "r", "--mode", "satellite"], "--mode: unknown value 'satellite' (one of peer,"),
    (["learner", "--run-dir", "r", "--seed", "-3"], "ennc-ql learner: error: seed must be at least 0, got -3"),
    (["learner", "--run-dir", "r", "--phase1-device", "cuda:7"], "--phase1-device cuda:7: this machine has"),
    (["learner", "--run-dir", "/proc/x"], "ennc-ql learner: error: --run-dir /proc/x: cannot write in /proc"),
    # actor
    (["actor", "--actor-id", "a/b"], "ennc-ql actor: error: actor_id: 'a/b' is not"),
    (["actor", "--seed", "-1"], "ennc-ql actor: error: seed must be at least 0, got -1"),
    (["actor", "--learn", "5-2"], "ennc-ql actor: error: --learn: bad robot range"),
    (["actor", "--arenas", "x"], "ennc-ql actor: error: --arenas: expected an integer, got 'x'"),
    (["actor", "--reward", "money"], "--reward: unknown value 'money' (one of paper, observed, eq2"),
    (["actor", "--formulation", "papper"], "--formulation: unknown value 'papper' (did you mean 'paper'?"),
    (["actor", "--zenoh-config", "alice.json5"], "the zenoh configuration authenticates as 'alice' but this"),
    (["actor", "--connect", "foo/bar"], "ennc-ql actor: error: zenoh could not open a session: Unicast not supported"),
    # router
    (["router", "--zenoh-config", "bad.json5"], "ennc-ql router: error: --zenoh-config bad.json5: not valid JSON5"),
    (["router", "--zenoh-config", "missing.json5"], "ennc-ql router: error: --zenoh-config missing.json5: no such"),
    (["router", "--mode", "peer"], "ennc-ql router: error: --mode peer: a router runs in router mode"),
    (["router", "--listen", "tcp/0.0.0.0:70000"], "--listen tcp/0.0.0.0:70000: expected HOST:PORT with a port"),
    (["router", "--lisen", "tcp/0.0.0.0:7447"], "ennc-ql router: error: unknown option '--lisen'; did you mean"),
    # secure init: ports, ids and the folder checked before a file is written.
    (["secure"], "ennc-ql secure: error: which command? one of init"),
    (["secure", "init"], "ennc-ql secure init: error: missing DIR"),
    (["secure", "init", "s", "--port", "0"], "--port: expected a TCP port from 1 to 65535, got '0'"),
    (["secure", "init", "s", "--port", "70000"], "--port: expected a TCP port from 1 to 65535, got '70000'"),
    (["secure", "init", "s", "--learner-id", "x/y"], "ennc-ql secure init: error: --learner-id: 'x/y' is not"),
    (["secure", "init", "s", "--learner-id", "observer"], "--learner-id observer: already the id of another"),
    (["secure", "init", "s", "--actors", "0"], "--actors: expected a positive integer of at most 10000"),
    (["secure", "init", "s", "--namespace", "a b"], "ennc-ql secure init: error: namespace chunk"),
    (["secure", "init", "s", "--host", "bad host"], "--host bad host: not a host name or an IP address"),
    (["secure", "init", "s", "--mount", "relative"], "--mount relative: give an absolute path"),
    (["secure", "init", "used"], "ennc-ql secure init: error: used: the folder holds files secure init did not"),
    (["secure", "init", "/proc/s"], "ennc-ql secure init: error: DIR /proc/s: cannot write in /proc"),
    # chaos
    (["chaos", "--faults", "nope"], "ennc-ql chaos: error: --faults: unknown fault 'nope'"),
    (["chaos", "--soak", "forever"], "ennc-ql chaos: error: --soak: 'forever' is not a duration"),
    (["chaos", "--duration", "10", "--soak", "1m"], "ennc-ql chaos: error: give --duration or --soak, not both"),
    (["chaos", "--no-secure", "--faults", "unauthenticated"], "unauthenticated tests TLS and authentication"),
    (["chaos", "--runs", "/proc/x"], "ennc-ql chaos: error: --runs /proc/x/chaos-"),
    # reproduce, ablate
    (["reproduce", "--methods", "nope"], "ennc-ql reproduce: error: --methods: unknown value 'nope'"),
    (["reproduce", "--quick", "--out", "/proc/x"], "ennc-ql reproduce: error: --out /proc/x: cannot write in /proc"),
    (["reproduce", "--jobs", "0"], "ennc-ql reproduce: error: --jobs: expected a positive integer, got '0'"),
    (["ablate"], "ennc-ql ablate: error: missing METHOD"),
    (["ablate", "enncql-collab-option2"], "METHOD: unknown value 'enncql-collab-option2'; did you mean"),
    (["ablate", "ennc-ql-collab-option2", "--set", "foo=1"], "ennc-ql ablate: error: unknown key 'foo'"),
    (["ablate", "ennc-ql-collab-option2", "--set", "budget.phase2.alpha=2"], "alpha must lie in (0, 1], got 2.0"),
    (
        ["ablate", "ennc-ql-collab-option2", "--set", "featurizer=raw"],
        "ennc-ql ablate: error: unknown featurizer 'raw'; known: local2d,",
    ),
    (["ablate", "ennc-ql-collab-option2", "--out", "/proc/x"], "error: --out /proc/x: cannot write in /proc"),
    # bench: one subcommand per benchmark, each with its own flags.
    (["bench"], "ennc-ql bench: error: which command? one of sim, ennc, transport, actor, broadcast, phase1"),
    (["bench", "everything"], "ennc-ql bench: error: unknown command 'everything'"),
    (["bench", "sim", "--patterns", "5"], "ennc-ql bench sim: error: unknown option '--patterns'"),
    (["bench", "actor", "--policy", "nothing.npz"], "ennc-ql bench actor: error: --policy nothing.npz: cannot be"),
    (["bench", "actor", "--policy", "text.npz"], "ennc-ql bench actor: error: --policy text.npz: not a policy file"),
    (["bench", "transport", "--actors", "0"], "ennc-ql bench transport: error: --actors: expected a positive"),
    (["bench", "ennc", "--patterns", "0"], "ennc-ql bench ennc: error: --patterns: expected a positive integer"),
    (["bench", "broadcast", "--prototypes"], "ennc-ql bench broadcast: error: --prototypes: expected at least"),
    (["bench", "sim", "--rerun", "save", "/proc/x.rrd"], "ennc-ql bench sim: error: --rerun save /proc: cannot"),
    # The edges (issue 23): values no command should take, files of the wrong kind or role, odd ids and namespaces.
    (["up", "--duration", "inf"], "ennc-ql up: error: --duration: expected a finite number, got 'inf'"),
    (["up", "--duration", "nan"], "ennc-ql up: error: --duration: expected a finite number, got 'nan'"),
    (["up", "--config", "infinite.toml"], "infinite.toml: key 'duration' must be a finite number, got inf"),
    (["chaos", "--duration", "inf"], "ennc-ql chaos: error: --duration: expected a positive finite number"),
    (["learner", "--run-dir", ""], "ennc-ql learner: error: --run-dir: expected a folder, got an empty value"),
    (["up", "--runs", ""], "ennc-ql up: error: --runs: expected a folder, got an empty value"),
    (["up", "--run-id", ""], "ennc-ql up: error: --run-id: '' is not"),
    (["router", "--namespace", "a b"], "ennc-ql router: error: --namespace: 'a b' is not 1-64 characters"),
    (["actor", "--namespace", "a//b"], "ennc-ql actor: error: --namespace: '' is not 1-64 characters"),
    (["learner", "--run-dir", "r", "--namespace", "a b"], "ennc-ql learner: error: --namespace: 'a b' is not"),
    (["router", "--zenoh-config", "alice.json5"], "authenticates as 'alice', not as the router; give the router's"),
    (["slurm", "train", "--time-limit", "2h"], "ennc-ql slurm train: error: --time-limit 2h: not a SLURM time"),
    (["slurm", "train", "--nodes", "5", "--actors", "2"], "--nodes 5 for --actors 2: the first node runs the learner"),
    (["slurm", "task", "empty", "--task", "-1"], "ennc-ql slurm task: error: --task=-1: expected a task number"),
    (["ablate", "fqi-mlp", "--set", "budget.phase2.alpha=0.1,0.2"], "fqi-mlp never reads budget.phase2"),
    (["reproduce", "--quick", "--out", "done"], "ennc-ql reproduce: error: --out done: holds results already"),
    (["ablate", "fqi-mlp", "--out", "done"], "ennc-ql ablate: error: --out done: holds results already"),
    # A configuration file of the wrong kind or of another process.
    (["up", "--config", "pickled.npy"], "ennc-ql up: error: pickled.npy: not a TOML configuration file (not UTF-8"),
    (["up", "--config", "run/checkpoint.npz"], "run/checkpoint.npz: an .npz archive (a policy file or a checkpoint)"),
    (["up", "--config", "bom.toml"], "ennc-ql up: error: bom.toml: unknown key 'duraton' (did you mean"),
    (["up", "--config", "learner.toml"], "ennc-ql up: error: learner.toml is a learner's configuration file"),
    (["up", "--config", "actor.toml"], "ennc-ql up: error: actor.toml is an actor's configuration file"),
    (["learner", "--run-dir", "r", "--config", "up.toml"], "error: up.toml is up's configuration file (ennc-ql up"),
    (["learner", "--run-dir", "r", "--config", "phase2.toml"], "phase2 is an actor's setting, not a learner's"),
    (["up", "--config", "seeded.toml"], "ennc-ql up: error: learner.seed = 5: up sets every learner's seed itself"),
    (["actor", "--config", "learner.toml"], "ennc-ql actor: error: learner.toml is a learner's configuration file"),
    # up --resume: a stopped run's own folder, with its own configuration, and time left.
    (["up", "--resume"], "ennc-ql up: error: --resume: needs a value"),
    (["up", "--resume", "nothing"], "ennc-ql up: error: --resume nothing: no such run folder"),
    (["up", "--resume", "run"], "ennc-ql up: error: --resume run: not a run folder of ennc-ql up (no up.toml"),
    (["up", "--resume", "stopped", "--duration", "5"], "--resume continues stopped with its own configuration"),
    (["up", "--resume", "stopped", "--run-id", "x"], "--run-id would change it"),
    (["up", "--resume", "unsaved"], "ennc-ql up: error: --resume unsaved: no checkpoint, the run was stopped before"),
    (["up", "--resume", "finished"], "ennc-ql up: error: --resume finished: the run trained its whole 10 s already"),
    (["learner", "--run-dir", "paper", "--resume"], "holds a run of formulation paper, and this learner's formulation"),
    # The edges (issue 55). Paths no file can have: every call on them fails with ENAMETOOLONG.
    (["up", "--runs", LONG], "ennc-ql up: error: --runs: a name in it is 300 bytes long, more than the"),
    (["up", "--config", LONG], "ennc-ql up: error: --config: a name in it is 300 bytes long"),
    (["up", "--resume", f"runs/{LONG}"], "ennc-ql up: error: --resume: a name in it is 300 bytes long"),
    (["eval", "--policy", f"{LONG}.npz"], "ennc-ql eval: error: --policy: a name in it is 304 bytes long"),
    (["eval", "--against", LONG], "ennc-ql eval: error: --against: a name in it is 300 bytes long"),
    (["eval", "--rerun", "save", f"{LONG}.rrd"], "ennc-ql eval: error: --rerun save: a name in it is 304 bytes long"),
    (["learner", "--run-dir", LONG], "ennc-ql learner: error: --run-dir: a name in it is 300 bytes long"),
    (["learner", "--run-dir", "r", "--zenoh-config", LONG], "error: --zenoh-config: a name in it is 300 bytes long"),
    (["reproduce", "--quick", "--out", LONG], "ennc-ql reproduce: error: --out: a name in it is 300 bytes long"),
    (["secure", "init", LONG], "ennc-ql secure init: error: DIR: a name in it is 300 bytes long"),
    (["bench", "actor", "--policy", LONG], "ennc-ql bench actor: error: --policy: a name in it is 300 bytes long"),
    # Counts past what one machine holds: refused with the bound, before a MemoryError or a machine full of processes.
    (["eval", "--trials", str(10**12)], "--trials: expected a positive integer of at most 100000 (all trials run side"),
    (["eval", "--steps", str(10**12)], "--steps: expected a positive integer of at most 100000 (a hundred times the"),
    (["actor", "--arenas", "100001"], "ennc-ql actor: error: arenas must be at most 100000, got 100001"),
    (["up", "--actor-arenas", str(10**8)], "ennc-ql up: error: actor: arenas must be at most 100000, got 100000000"),
    (["learner", "--run-dir", "r", "--final-eval-trials", str(10**6)], "final_eval_trials must be at most 100000"),
    (
        ["bench", "actor", "--arenas", str(10**9)],
        "bench actor: error: --arenas: expected a positive integer of at most",
    ),
    (["up", "--actors", "100000"], "ennc-ql up: error: --actors 100000: up runs at most"),
    (["learner", "--run-dir", "r", "--store-capacity", str(10**15)], "store_capacity must be at most 50000000"),
    (["up", "--learner-store-capacity", str(10**15)], "store_capacity must be at most 50000000"),
    (["secure", "init", "s", "--actors", str(10**7)], "--actors: expected a positive integer of at most 10000"),
    (["up", "--recording-id", ""], "ennc-ql up: error: --recording-id: expected a recording id, got an empty value"),
    (["up", "--serial", "--actors", "100000"], "ennc-ql up: error: --actors 100000: up runs at most"),
    # Policies whose tables hold a value no argmax can read, wherever a policy is loaded.
    (["eval", "--policy", "nan.npz"], "error: --policy nan.npz: the Q table of robot 3 holds NaN (1 of 8 values)"),
    (["eval", "--against", "inf.npz"], "error: --against inf.npz: the Q table of robot 3 holds infinity (1 of 8"),
    (["bench", "actor", "--policy", "nan.npz"], "ennc-ql bench actor: error: --policy nan.npz: the Q table of robot 3"),
    (["learner", "--run-dir", "poisoned", "--resume"], "--resume: poisoned/checkpoint.npz: Q table 3 holds NaN"),
    (["up", "--resume", "poisoned"], "--resume poisoned: poisoned/checkpoint.npz: Q table 3 holds NaN (1 of 8 values)"),
    # Names and empty values: the flag named, the closest choice, the command's own flags in the advice.
    (["--bogus"], "ennc-ql: error: unknown option '--bogus'"),
    (["-v", "--bogus", "eval"], "ennc-ql: error: unknown option '--bogus'"),
    (["eval", "--policy", ""], "ennc-ql eval: error: --policy: expected a hand-made controller or a policy file, got"),
    (["eval", "--against", ""], "ennc-ql eval: error: --against: expected a hand-made controller or a policy file"),
    (["up", "--config", ""], "ennc-ql up: error: --config: expected a file, got an empty value"),
    (["actor", "--zenoh-config", ""], "ennc-ql actor: error: --zenoh-config: expected a file, got an empty value"),
    (["router", "--zenoh-config", "empty"], "ennc-ql router: error: --zenoh-config empty: a folder, not a file"),
    (["learner", "--run-dir", "r", "--zenoh-config", "empty"], "--zenoh-config empty: a folder, not a file"),
    (
        ["learner", "--run-dir", "paper"],
        "--run-dir paper holds a run already (checkpoint.npz), which this would overwrite: continue it with --resume, "
        "or give another --run-dir",
    ),
    (
        ["up", "--runs", ".", "--run-id", "stopped"],
        "continue it with ennc-ql up --resume stopped, or give a fresh",
    ),
    (
        ["up", "--runs", ".", "--run-id", "done"],
        "(results.json), which this would overwrite: give a fresh --run-id",
    ),
    (["slurm", "train", "--runs", ".", "--run-id", "stopped"], "(checkpoint.npz), which this would overwrite: give a"),
    (["eval", "--policy", "a-cmomt"], "--policy: unknown policy 'a-cmomt'; did you mean 'a-cmommt'? (one of random,"),
    (["eval", "--against", "forcerecall"], "--against: unknown policy 'forcerecall'; did you mean 'force-recall'?"),
    (["eval", "--policy", "missing.npz"], "ennc-ql eval: error: --policy missing.npz: no such policy file"),
]


def fixtures(folder: Path) -> None:
    """What some rows point at: files that are not what a flag needs, and folders already used."""
    (folder / "notes.txt").write_text("a file where a folder is expected\n")
    (folder / "text.npz").write_text("not an archive\n")
    np.save(folder / "pickled.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (folder / "run").mkdir()
    np.savez(folder / "run" / "checkpoint.npz", store_reward=np.zeros(3))
    (folder / "empty").mkdir()
    (folder / "used").mkdir()
    (folder / "used" / "x").mkdir()
    (folder / "used" / "x" / "notes.txt").write_text("a file of the user's\n")
    (folder / "used" / "checkpoint.npz").write_text("not an archive\n")
    (folder / "bad.json5").write_text("{bad\n")
    (folder / "unknown.json5").write_text('{mode: "peer", foo: 1}\n')
    (folder / "unknown.toml").write_text("duraton = 5\n")
    auth = {"transport": {"auth": {"usrpwd": {"user": "alice", "password": "secret"}}}}
    (folder / "alice.json5").write_text(json.dumps(auth))
    edge_fixtures(folder)


def edge_fixtures(folder: Path) -> None:
    """Files of the edges: another process's configuration, a byte-order mark, stopped and finished runs."""
    from actors.config import ActorConfig
    from tools.cluster import UP_PRESETS, UpConfig, child_configs, write_configs
    from tools.config import load_config

    (folder / "infinite.toml").write_text("duration = inf\n")
    (folder / "bom.toml").write_bytes("\ufeffduraton = 5\n".encode())
    (folder / "phase2.toml").write_text("min_tuples = 5000\n[phase2]\nalpha = 0.2\n")
    (folder / "seeded.toml").write_text("seed = 1\n[learner]\nseed = 5\n")
    config = load_config(UpConfig, defaults=UP_PRESETS)
    learner, _ = child_configs(config)
    (folder / "learner.toml").write_text(dump_config(learner))
    (folder / "actor.toml").write_text(dump_config(ActorConfig(actor_id="actor-3")))
    (folder / "up.toml").write_text(dump_config(config))
    short = load_config(UpConfig, defaults={**UP_PRESETS, "duration": 10.0})
    for name, elapsed in (("stopped", 4.0), ("unsaved", None), ("finished", 10.0)):
        (folder / name).mkdir()
        write_configs(short, *child_configs(short), folder / name)
        if elapsed is not None:
            meta = {"elapsed": elapsed, "config": {"formulation": short.formulation}}
            np.savez(folder / name / "checkpoint.npz", meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    (folder / "paper").mkdir()
    meta = {"elapsed": 3.0, "config": {"formulation": "paper"}}
    np.savez(folder / "paper" / "checkpoint.npz", meta=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    (folder / "done").mkdir()
    (folder / "done" / "results.json").write_text("{}\n")
    poisoned_fixtures(folder, short)


def poisoned_fixtures(folder: Path, config: UpConfig) -> None:
    """Policy files and a stopped run whose Q tables hold a NaN or an infinity (robot 3's table, its cell 1)."""
    from algorithm.policy_file import save_policy
    from sim import scenario
    from tests.algorithm.test_selection import constant
    from tools.cluster import child_configs, write_configs

    policy = constant(0, version=1)
    for name, bad in (("nan", np.nan), ("inf", np.inf)):
        tables = np.zeros((10, policy.tables.shape[1]), np.float32)
        tables[3, 1] = bad
        per_robot = dataclasses.replace(policy, tables=tables, robot_table=np.arange(10))
        save_policy(per_robot, scenario(), folder / f"{name}.npz")
    (folder / "poisoned").mkdir()
    write_configs(config, *child_configs(config), folder / "poisoned")
    meta = {"elapsed": 4.0, "config": {"formulation": config.formulation}}
    tables = np.zeros((10, 8))
    tables[3, 1] = np.nan
    np.savez(
        folder / "poisoned" / "checkpoint.npz", meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), tables=tables
    )


COMMAND_WORDS = {"eval", "up", "learner", "actor", "router", "secure", "init", "chaos", "reproduce", "ablate", "bench"}
COMMAND_WORDS |= {"sim", "ennc", "transport", "broadcast", "phase1", "slurm", "train", "task"}


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fixtures, made once (writing the configuration files takes 0.2 s): each row gets a copy."""
    folder = tmp_path_factory.mktemp("fixtures")
    fixtures(folder)
    return folder


@pytest.fixture
def folder(template: Path, tmp_path: Path) -> Path:
    """A fresh working folder holding the fixtures."""
    shutil.copytree(template, tmp_path, dirs_exist_ok=True)
    return tmp_path


def command_of(argv: list[str]) -> str:
    """The command that answers: the words that name a command and its subcommand, up to the first other word."""
    words: list[str] = []
    for word in argv:
        if word not in COMMAND_WORDS:
            break
        words.append(word)
    return " ".join(["ennc-ql", *words])


def tree(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


Runner = Callable[[list[str], Path, dict[str, str] | None], subprocess.CompletedProcess[str]]


def run(argv: list[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``ennc-ql argv`` in ``cwd`` (with ``env`` added to the environment); past the timeout its whole process group
    is killed, so nothing is left."""
    proc = subprocess.Popen(
        [str(ENNC_QL), *argv],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "COLUMNS": "120", **(env or {})},
    )
    try:
        out, err = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        pytest.fail(f"ennc-ql {' '.join(argv)} started instead of failing; stderr:\n{err[-2000:]}")
    return subprocess.CompletedProcess(argv, proc.returncode, out, err)


def run_forked(
    server: ForkServer, argv: list[str], cwd: Path, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """:func:`run`, in a fork of the server: the same environment, timeout and kill."""
    code, out, err, timed_out = server.run(argv, cwd, {**os.environ, "COLUMNS": "120", **(env or {})}, TIMEOUT_S)
    if timed_out:
        pytest.fail(f"ennc-ql {' '.join(argv)} started instead of failing; stderr:\n{text(err)[-2000:]}")
    return subprocess.CompletedProcess(argv, code, text(out), text(err))


@pytest.fixture(scope="module")
def forked() -> Iterator[Runner]:
    """:func:`run` through one fork server for the module: the console script's own entry point, preloaded."""
    [script] = entry_points(group="console_scripts", name="ennc-ql")
    server = ForkServer(ENNC_QL, script.value, PRELOAD)
    yield partial(run_forked, server)
    server.close()
    assert server.proc.returncode == 0 and server.stderr() == "", server.stderr()


HIDDEN = ("iptables", "iptables-legacy", "iptables-nft", "ip6tables", "sbatch", "srun", "slurmd", "Xvfb", "podman")
"""The optional system programs a machine may lack: with them hidden, every row must meet the contract just the same
(a notice about what is missing never comes before the error)."""


@pytest.fixture(scope="module")
def bare_path(tmp_path_factory: pytest.TempPathFactory) -> str:
    """A PATH of one folder linking every program on this PATH but the optional ones (:data:`HIDDEN`)."""
    folder = tmp_path_factory.mktemp("bare-bin")
    for directory in reversed(os.environ.get("PATH", "").split(os.pathsep)):
        for program in Path(directory).glob("*") if directory and Path(directory).is_dir() else []:
            if program.name not in HIDDEN and os.access(program, os.X_OK) and program.is_file():
                (folder / program.name).unlink(missing_ok=True)
                (folder / program.name).symlink_to(program)
    return str(folder)


IDS = [" ".join(argv) or "(nothing)" for argv, _ in ROWS]


@pytest.mark.parametrize(("argv", "message"), ROWS, ids=IDS)
def test_bad_input_is_one_line_exit_2_and_nothing_left(
    argv: list[str], message: str, folder: Path, forked: Runner
) -> None:
    assert_contract(forked, argv, message, folder)


@pytest.mark.parametrize(("argv", "message"), ROWS, ids=IDS)
def test_without_iptables_slurm_or_xvfb_every_row_meets_the_contract_too(
    argv: list[str], message: str, folder: Path, bare_path: str, forked: Runner
) -> None:
    assert_contract(forked, argv, message, folder, {"PATH": bare_path})


SAME_ROWS = [["evl"], ["up", "--actors", "0"], ["learner", "--run-dir", "r", "--phase1-device", "cuda:7"]]
"""A usage error of the top parser, one of a command's own checks, and a torch device check."""


@pytest.mark.parametrize("argv", SAME_ROWS, ids=[" ".join(argv) for argv in SAME_ROWS])
def test_a_forked_row_answers_as_the_console_script(argv: list[str], folder: Path, forked: Runner) -> None:
    """What stands for the console script above says, byte for byte, what the script says."""
    script, fork = run(argv, folder), forked(argv, folder, None)
    assert (fork.returncode, fork.stdout, fork.stderr) == (script.returncode, script.stdout, script.stderr)


def assert_contract(
    run: Runner, argv: list[str], message: str, folder: Path, env: dict[str, str] | None = None
) -> None:
    before = tree(folder)
    result = run(argv, folder, env)
    lines = result.stderr.splitlines()
    command = command_of(argv)
    assert result.returncode == 2, result.stderr
    assert lines and lines[0].startswith(f"{command}: error: "), result.stderr
    assert message in lines[0], result.stderr
    # At most a short usage of the same command after the error, as clap's tools print it.
    assert len(lines) <= 2 and all(line.startswith(f"usage: {command} [OPTIONS]") for line in lines[1:]), lines
    for leak in ("Traceback", ".rs:", "allow_pickle", "``", ":mod:"):
        assert leak not in result.stderr
    assert result.stdout == ""
    assert tree(folder) == before  # no run folder, no created directory, no recording


def test_a_port_in_use_is_one_line_and_leaves_no_run_folder(tmp_path: Path) -> None:
    """Zenoh's own refusal, once the session opens, follows the contract too: one line, no Rust path, no folder."""
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        result = run(["learner", "--run-dir", "r", "--listen", f"tcp/127.0.0.1:{port}", "--duration", "1"], tmp_path)
    assert result.returncode == 2
    [line] = result.stderr.splitlines()
    assert line.startswith("ennc-ql learner: error: zenoh could not open a session: Can not create a new TCP listener")
    assert f"127.0.0.1:{port}" in line and "Address already in use" in line and ".rs:" not in line
    assert list(tmp_path.iterdir()) == []


ENV_ROWS: list[tuple[dict[str, str], list[str], str]] = [
    ({"SLURM_ARRAY_TASK_ID": "abc"}, ["slurm", "task", "empty"], "SLURM_ARRAY_TASK_ID='abc': expected a task number"),
    ({"SLURM_ARRAY_TASK_ID": ""}, ["slurm", "task", "empty"], "SLURM_ARRAY_TASK_ID='': expected a task number"),
    # A headless machine (no viewer runs on port 9876 during the tests): before a process starts, with the way out.
    ({"DISPLAY": "", "WAYLAND_DISPLAY": ""}, ["up", "--rerun", "spawn"], "--rerun spawn: no display for the viewer"),
    (
        {"DISPLAY": "", "WAYLAND_DISPLAY": ""},
        ["eval", "--rerun", "spawn"],
        "rerun --serve-web --bind 127.0.0.1 FILE.rrd",
    ),
]


@pytest.mark.parametrize(("env", "argv", "message"), ENV_ROWS, ids=[" ".join(a) + f" {e}" for e, a, _ in ENV_ROWS])
def test_a_bad_environment_variable_meets_the_contract_too(
    env: dict[str, str], argv: list[str], message: str, folder: Path, forked: Runner
) -> None:
    assert_contract(forked, argv, message, folder, env)


def test_help_on_an_ascii_terminal_is_printed_not_a_traceback(tmp_path: Path) -> None:
    result = run(["up", "--help"], tmp_path, {"PYTHONIOENCODING": "ascii"})
    assert result.returncode == 0 and result.stderr == ""
    assert result.stdout.startswith("usage: ennc-ql up") and "Ctrl-C" in result.stdout


@pytest.mark.parametrize("reader", ["gone at once", "head -1"])
def test_a_reader_that_goes_away_ends_the_command_quietly(reader: str, tmp_path: Path) -> None:
    """``ennc-ql eval ... | head -1``: once the reader is gone the command stops with the status of SIGPIPE (or 0
    if it had written everything already), saying nothing."""
    proc = subprocess.Popen(
        [str(ENNC_QL), "eval", "--trials", "3", "--steps", "20"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "COLUMNS": "120"},
    )
    assert proc.stdout is not None and proc.stderr is not None
    if reader == "head -1":
        assert proc.stdout.readline().startswith(b"policy a-cmommt")
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait(TIMEOUT_S) in (0, 128 + signal.SIGPIPE)
    for leak in ("Traceback", "BrokenPipe", "Exception ignored", "error"):
        assert leak not in err, err


@pytest.mark.parametrize("closed", [">&-", "2>&-", ">&- 2>&-", "<&-"])
def test_closed_standard_streams_are_no_traceback(closed: str, tmp_path: Path) -> None:
    """A command started with a standard stream closed runs as with /dev/null there: ``eval`` scores its trials and
    exits 0, and what it prints lands nowhere (not in a file that took the stream's descriptor)."""
    command = f"{ENNC_QL} eval --trials 2 --steps 20 --json {closed}; echo status=$? >&3"
    done = subprocess.run(
        ["bash", "-c", f"exec 3>&1; {{ {command}; }} 2>{tmp_path / 'err'}"],
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
        cwd=tmp_path,
    )
    assert "status=0" in done.stdout, (done.stdout, (tmp_path / "err").read_text())
    err = (tmp_path / "err").read_text()
    assert "Traceback" not in err and "NoneType" not in err
    if ">&-" not in closed.replace("2>&-", ""):  # stdout open: the result is printed there
        assert '"coverage_mean"' in done.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["err"]


FULL_ROWS = [
    (["eval", "--trials", "2", "--steps", "20"], "ennc-ql eval"),
    (["eval", "--help"], "ennc-ql eval"),
    (["--version"], "ennc-ql"),
]
"""A command's result, a command's help page and the top-level parser's own output."""


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full on this machine")
@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "PYTHONUNBUFFERED"])
@pytest.mark.parametrize(("argv", "command"), FULL_ROWS, ids=[" ".join(argv) for argv, _ in FULL_ROWS])
def test_an_output_that_refuses_what_is_written_is_one_line_and_status_1(
    argv: list[str], command: str, buffered: bool, tmp_path: Path
) -> None:
    """``> /dev/full``: every write fails (ENOSPC), at the last flush or, unbuffered, at once. The command says so in
    one line, as coreutils do, never in a traceback, in the catch-all's words, or not at all (argparse drops a failed
    write of a help page and exits 0)."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"} | {"COLUMNS": "120"}
    if not buffered:
        env["PYTHONUNBUFFERED"] = "1"
    with open("/dev/full", "w") as full:
        done = subprocess.run(
            [str(ENNC_QL), *argv],
            stdout=full,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            cwd=tmp_path,
            timeout=TIMEOUT_S,
        )
    assert done.returncode == 1, done.stderr
    assert done.stderr.splitlines() == [f"{command}: error: cannot write to standard output (No space left on device)"]
    assert list(tmp_path.iterdir()) == []


def test_rerun_serve_on_a_taken_port_is_one_line_before_anything_starts(tmp_path: Path) -> None:
    """Rerun's server only logs a taken port and serves nothing: ``--rerun serve`` checks the port first."""
    with socket.socket() as busy:
        busy.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            busy.bind(("0.0.0.0", 9876))
        except OSError:
            pytest.skip("port 9876 is in use on this machine already (a Rerun viewer?)")
        busy.listen()
        result = run(["eval", "--trials", "1", "--steps", "10", "--rerun", "serve"], tmp_path)
    assert result.returncode == 2
    [line] = result.stderr.splitlines()
    assert line.startswith("ennc-ql eval: error: --rerun serve: port 9876 is taken")
    assert "--rerun connect rerun+http://127.0.0.1:9876/proxy" in line
    assert result.stdout == "" and list(tmp_path.iterdir()) == []
