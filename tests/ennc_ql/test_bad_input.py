"""One error contract for every command, through the real console script: bad input gets one line,
``ennc-ql <command>: error: <what>``, at most one short usage line after it, exit status 2, and leaves nothing
behind (no run folder, no created directory, no recording), before anything starts.

Each row is a command line and the words its error must carry. Every row runs ``ennc-ql`` in a fresh working
folder that holds the fixtures below; the folder must hold exactly those afterwards."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ENNC_QL = Path(sys.executable).with_name("ennc-ql")
TIMEOUT_S = 90.0
"""A row that started something it should not have is stopped here (and fails): none takes a second to answer."""

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
    (["eval", "--trials", "0"], "ennc-ql eval: error: --trials: expected a positive integer, got '0'"),
    (["eval", "--steps", "x"], "ennc-ql eval: error: --steps: expected a positive integer, got 'x'"),
    (["eval", "--scenario", "cmommt-v2"], "--scenario: unknown value 'cmommt-v2'; did you mean 'cmommt-v1'?"),
    (["eval", "--policy", "greedy"], "ennc-ql eval: error: --policy greedy: neither a hand-made controller"),
    (["eval", "--policy", "text.npz"], "--policy text.npz: not a policy file (not an .npz archive of plain arrays)"),
    (["eval", "--policy", "pickled.npy"], "--policy pickled.npy: not a policy file (not an .npz archive"),
    (["eval", "--policy", "run"], "ennc-ql eval: error: --policy run: a folder, not a policy file"),
    (["eval", "--policy", "run/checkpoint.npz"], "--policy run/checkpoint.npz: not a policy file (no header,"),
    (["eval", "--record-trial", "5", "--trials", "2"], "--record-trial 5: only trials 0 to 1 run (--trials)"),
    (["eval", "--rerun", "save", "/proc/x.rrd"], "ennc-ql eval: error: --rerun save /proc: cannot write in /proc"),
    (["eval", "--rerun", "save", "run"], "ennc-ql eval: error: --rerun save run: a folder, not a file"),
    (["eval", "--rerun", "bogus"], "ennc-ql eval: error: --rerun: unknown Rerun sink 'bogus'"),
    (["eval", "--rerun", "connect", "http://x"], "ennc-ql eval: error: --rerun: 'connect' needs a URL like"),
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
    (["secure", "init", "s", "--actors", "0"], "--actors: expected a positive integer, got '0'"),
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
        "ennc-ql ablate: error: featurizer: unknown 'raw'; known: local2d,",
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
    (folder / "used" / "x" / "report.json").write_text("{}\n")
    (folder / "used" / "checkpoint.npz").write_text("not an archive\n")
    (folder / "bad.json5").write_text("{bad\n")
    (folder / "unknown.json5").write_text('{mode: "peer", foo: 1}\n')
    (folder / "unknown.toml").write_text("duraton = 5\n")
    auth = {"transport": {"auth": {"usrpwd": {"user": "alice", "password": "secret"}}}}
    (folder / "alice.json5").write_text(json.dumps(auth))


COMMAND_WORDS = {"eval", "up", "learner", "actor", "router", "secure", "init", "chaos", "reproduce", "ablate", "bench"}
COMMAND_WORDS |= {"sim", "ennc", "transport", "broadcast", "phase1"}


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
def test_bad_input_is_one_line_exit_2_and_nothing_left(argv: list[str], message: str, tmp_path: Path) -> None:
    assert_contract(argv, message, tmp_path)


@pytest.mark.parametrize(("argv", "message"), ROWS, ids=IDS)
def test_without_iptables_slurm_or_xvfb_every_row_meets_the_contract_too(
    argv: list[str], message: str, tmp_path: Path, bare_path: str
) -> None:
    assert_contract(argv, message, tmp_path, {"PATH": bare_path})


def assert_contract(argv: list[str], message: str, tmp_path: Path, env: dict[str, str] | None = None) -> None:
    fixtures(tmp_path)
    before = tree(tmp_path)
    result = run(argv, tmp_path, env)
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
    assert tree(tmp_path) == before  # no run folder, no created directory, no recording


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
