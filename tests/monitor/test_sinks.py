"""The ``--rerun`` / ``--recording-id`` flags and the no-op monitor."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pytest

from monitor import Monitor, Sink, add_rerun_args, open_monitor, sink_from_args

REPO = Path(__file__).resolve().parents[2]


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="proc")
    add_rerun_args(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        ((), Sink("off")),
        (("--rerun", "off"), Sink("off")),
        (("--rerun", "save", "runs/x/rerun/learner.rrd"), Sink("save", "runs/x/rerun/learner.rrd")),
        (("--rerun", "spawn"), Sink("spawn")),
        (("--rerun", "serve"), Sink("serve")),
        (
            ("--rerun", "connect", "rerun+http://10.0.0.2:9876/proxy"),
            Sink("connect", "rerun+http://10.0.0.2:9876/proxy"),
        ),
        (("--rerun", "connect", "rerun://viewer:9876/proxy"), Sink("connect", "rerun://viewer:9876/proxy")),
    ],
)
def test_good_sinks_parse(argv: tuple[str, ...], expected: Sink) -> None:
    assert sink_from_args(parse(*argv)) == expected


def test_recording_id_is_passed_through() -> None:
    args = parse("--rerun", "spawn", "--recording-id", "run-42")
    assert args.recording_id == "run-42"
    assert parse().recording_id is None


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (("--rerun", "save"), "'save' needs a path"),
        (("--rerun", "connect"), "'connect' needs a URL"),
        (("--rerun", "connect", "http://127.0.0.1:9876/proxy"), "rerun+http://"),
        (("--rerun", "connect", "rerun+http://127.0.0.1:9876/"), "path /proxy"),
        (("--rerun", "spawn", "extra"), "'spawn' takes no argument"),
        (("--rerun", "off", "x"), "'off' takes no argument"),
        (("--rerun", "serve", "9877"), "'serve' takes no argument"),
        (("--rerun", "save", "a.rrd", "b.rrd"), "at most one argument"),
        (("--rerun", "file"), "unknown Rerun sink 'file'"),
        (("--rerun",), "expected at least one argument"),
    ],
)
def test_bad_sinks_are_argparse_errors(argv: tuple[str, ...], message: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        parse(*argv)
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err


def test_sink_validates_when_built_directly() -> None:
    with pytest.raises(ValueError, match="needs a path"):
        Sink("save")
    with pytest.raises(ValueError, match="takes no argument"):
        Sink("spawn", "x")


def test_off_gives_the_no_op_monitor() -> None:
    monitor = open_monitor(Sink("off"), process="test", recording_id="r")
    assert type(monitor) is Monitor and not monitor.enabled


NO_OP_SCRIPT = """
import sys
import numpy as np
import monitor
from monitor import Sink, open_monitor, paths
m = open_monitor(Sink("off"), process="learner", recording_id="r")
with m:
    m.use_clock(lambda: 1.0)
    m.send_blueprint(["actor-0"], arena_radius=1000.0, sensing_range=150.0)
    m.arena(paths.actor_arena("actor-0"), np.zeros((10, 2)), np.ones((10, 2)),
            sensing_range=150.0, arena_radius=1000.0, sim_step=0)
    m.prototypes([np.zeros((3, 6))], [np.zeros(3)], policy_version=1)
    m.q_stats([np.zeros((3, 8))], policy_version=1)
    m.eval_coverage(50.0, policy_version=1)
    m.reference_levels({"random": 16.6})
    m.final_coverage(50.0, trials=50, policy_version=1)
    m.learner_metrics(learner_step=1, policy_version=1, tuples_per_s=1.0, live_actors=1, store_size=1,
                      rejected=0, lag={"actor-0": 0})
    m.actor_metrics("actor-0", sim_step=5, coverage=1.0, mean_reward=0.0, tuples_per_s=1.0)
    m.scalars("x", {"y": 1.0}, sim_step=1)
assert "rerun" not in sys.modules, "the no-op monitor imported rerun"
assert "matplotlib" not in sys.modules, "the no-op monitor imported matplotlib"
print("ok")
"""


def test_no_op_monitor_never_imports_rerun() -> None:
    done = subprocess.run(
        [sys.executable, "-c", NO_OP_SCRIPT], cwd=REPO, capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"


PROCESSES_SCRIPT = """
import sys
import ennc_ql.cli, ennc_ql.learner, ennc_ql.actor, ennc_ql.up, learner.service, actors.actor
from ennc_ql.cli import build_parser
args = build_parser().parse_args(["actor", "--actor-id", "a0"])
assert args.rerun.kind == "off"
print(sorted(m for m in ("rerun", "rerun_bindings") if m in sys.modules))
"""


def test_processes_with_monitoring_off_never_import_rerun() -> None:
    done = subprocess.run(
        [sys.executable, "-c", PROCESSES_SCRIPT], cwd=REPO, capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_spawn_is_checked_before_anything_starts(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """``--rerun spawn`` finds the venv's own viewer without the venv on PATH, and says why it cannot show one: no
    viewer, or no display (with the ways that work on a server); a viewer already listening is always fine."""
    import socket
    import sys

    from monitor import sinks

    monkeypatch.setenv("PATH", str(tmp_path))  # nothing on PATH: the viewer beside python is found all the same
    assert sinks.viewer_executable() == str(Path(sys.executable).parent / "rerun")
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]  # nobody listens there once closed
    monkeypatch.setenv("DISPLAY", ":0")
    assert sinks.spawn_problem(port) is None
    monkeypatch.delenv("DISPLAY")
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    problem = sinks.spawn_problem(port)
    assert problem is not None and "no display" in problem and "rerun --serve-web --bind 127.0.0.1 FILE.rrd" in problem
    monkeypatch.setattr(sinks, "viewer_executable", lambda: None)
    assert "no Rerun viewer here" in (sinks.spawn_problem(port) or "")
    with socket.create_server(("127.0.0.1", 0)) as viewer:  # a viewer runs: spawn streams to it
        assert sinks.spawn_problem(viewer.getsockname()[1]) is None
