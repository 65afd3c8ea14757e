"""``ennc-ql up`` stopped by real signals at the worst moments, and ``up --resume``: SIGTERM during phase 1, Ctrl-C
just after a checkpoint and twice in a row, three signals at once, and SIGKILL to ``up`` itself. Each time no process
of the run is left (every descendant seen while it ran, and every process of their process group), the report is
written and says how the run stopped and how to continue it, and the exit status is 128 + the signal. A resumed run
keeps every tuple the stopped one stored and acknowledged, and its policy versions follow the stopped run's."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import threading
from pathlib import Path
from typing import Any

import psutil
import pytest

from tests.e2e import ACTOR_PACE, ennc_ql
from tests.e2e.cluster import checkpoint_version, wait_for

pytestmark = pytest.mark.slow

SMALL = [
    "--actors=2",
    "--actor-arenas=16",
    f"--actor-max-tuples-per-s={ACTOR_PACE}",
    "--actor-batch-size=1024",
    "--learner-phase1-max-patterns=300",
    "--learner-phase1-n-cycles=10",
    "--learner-phase1-seed-prototypes=32",  # the default 512 seeds take the first fit 10-16 s on loaded cores
    "--learner-phase1-max-iterations=1",
    "--learner-checkpoint-interval=1",
    "--learner-broadcast-interval=1",
    "--learner-eval-interval=1000",
    "--learner-eval-trials=1",
    "--learner-final-eval-trials=2",
    "--learner-margin-trials=2",  # the default 300 validation trials x 7 margins take a wind-down 20-60 s
    "--rerun=off",
]
EXIT = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 129}


class Up:
    """One ``ennc-ql up`` in a session of its own (so the test's signals reach it alone), its stdout and stderr in
    files, every descendant and process group noted while it runs (orphans cannot be found once it exited)."""

    def __init__(self, tmp_path: Path, name: str, *argv: str) -> None:
        self.out, self.err = tmp_path / f"{name}.out", tmp_path / f"{name}.err"
        with open(self.out, "wb") as out, open(self.err, "wb") as err:
            self.proc = subprocess.Popen(
                ennc_ql("up", *argv), stdin=subprocess.DEVNULL, stdout=out, stderr=err, start_new_session=True
            )
        self.seen: dict[int, psutil.Process] = {}
        self.groups: set[int] = set()
        self._done = threading.Event()
        self._watcher = threading.Thread(target=self._watch, daemon=True)
        self._watcher.start()

    def _watch(self) -> None:
        while not self._done.wait(0.2):
            try:
                for child in psutil.Process(self.proc.pid).children(recursive=True):
                    self.seen.setdefault(child.pid, child)
                    self.groups.add(os.getpgid(child.pid))
            except (psutil.NoSuchProcess, ProcessLookupError):
                continue

    def send(self, sig: int) -> None:
        """``sig`` to ``up``, once it said that it took the signals before (two signals of one kind that arrive
        together are one to Linux: a person's Ctrl-Cs are seconds apart)."""
        said = self.stderr().count("ennc-ql up: SIG")
        self.proc.send_signal(sig)
        wait_for(lambda: self.stderr().count("ennc-ql up: SIG") > said, 30, f"up to take {signal.Signals(sig).name}")

    def wait(self, timeout: float) -> int:
        """``up``'s exit status; it and everything it started are killed on a timeout (the test fails)."""
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill_all()
            raise AssertionError(
                f"up still running after {timeout:.0f} s; stderr ends:\n{self.stderr()[-3000:]}"
            ) from None
        finally:
            self._done.set()
            self._watcher.join()
        return code

    def kill_all(self) -> None:
        for p in [psutil.Process(self.proc.pid), *self.seen.values()]:
            if alive(p):
                p.kill()
        self.proc.wait()

    def left(self) -> list[str]:
        """Every process of the run still running: descendants seen, and members of their process groups."""
        left = [f"{p.pid} {p.cmdline()}" for p in self.seen.values() if alive(p)]
        for p in psutil.process_iter():
            try:
                if p.pid != os.getpid() and os.getpgid(p.pid) in self.groups - {os.getpgid(0)}:
                    left.append(f"{p.pid} (group {os.getpgid(p.pid)}) {p.cmdline()}")
            except (psutil.Error, ProcessLookupError):
                continue
        return left

    def stderr(self) -> str:
        return self.err.read_text(errors="replace")

    def stdout(self) -> str:
        return self.out.read_text(errors="replace")

    def __enter__(self) -> Up:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc.poll() is None:
            self.kill_all()
        self._done.set()


def alive(p: psutil.Process) -> bool:
    try:
        return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def stored(run_dir: Path) -> int:
    """Tuples the learner's checkpoint holds (0 before its first)."""
    import numpy as np

    try:
        with np.load(run_dir / "checkpoint.npz") as data:
            return int(json.loads(data["intake_meta"].tobytes())["received"])
    except (OSError, ValueError, KeyError):
        return 0


def report(run_dir: Path) -> dict[str, Any]:
    out: dict[str, Any] = json.loads((run_dir / "report.json").read_text())
    return out


def acked(out: dict[str, Any]) -> int:
    return sum(a["tuples_acked"] for a in out["actors_sent"].values())


def assert_stopped(up: Up, run_dir: Path, sig: int, learner: str) -> dict[str, Any]:
    """The contract of a stopped run: its status, no process left, the report, and the command that continues."""
    code = up.wait(180)
    assert code == EXIT[sig], f"exit {code}\n{up.stderr()[-3000:]}"
    assert up.seen, "up started no child"
    wait_for(lambda: not up.left(), 10, "every process of the run to be gone")  # reaped: at once, or dying now
    out = report(run_dir)
    stop = out["interrupted"]
    assert stop["signal"] == signal.Signals(sig).name and stop["learner"] == learner, stop
    assert stop["resume"] == f"ennc-ql up --resume {run_dir}"
    line = f"interrupted by {signal.Signals(sig).name} at {stop['at_s']:.0f}/{stop['duration_s']:g} s of training"
    assert line in up.stdout() and stop["resume"] in up.stdout(), up.stdout()
    assert line[0].upper() + line[1:] in (run_dir / "report.md").read_text()
    # One clock: the progress line's last time (it never runs back) is the report's, to a second.
    shown = [int(n) for n in re.findall(r"^up \[(\d+)/", up.stderr(), re.MULTILINE)]
    assert shown == sorted(shown) and abs(shown[-1] - stop["at_s"]) <= 1.0, (shown[-5:], stop["at_s"])
    assert (run_dir / "learning_curve.png").stat().st_size > 0
    return out


def test_sigterm_during_phase_1_then_resume_keeps_every_acknowledged_tuple(tmp_path: Path) -> None:
    run_dir = tmp_path / "r"
    flags = [*SMALL, "--duration=30", "--learner-min-tuples=100000", "--runs", str(tmp_path), "--run-id", "r"]
    with Up(tmp_path, "first", *flags) as up:
        # Phase 1: the learner checkpointed experience, and no policy exists yet.
        wait_for(lambda: stored(run_dir) > 0, 120, "a checkpoint holding experience")
        assert checkpoint_version(run_dir) == 0
        up.send(signal.SIGTERM)
        first = assert_stopped(up, run_dir, signal.SIGTERM, learner="finished")
    # The signal came before any policy (the checkpoint above holds version 0); on loaded cores the experience the
    # actors hand in while winding down can still complete the first fit, so the stopped run may end with one.
    assert first["tuples_received"] > 0
    assert first["tuples_received"] >= acked(first) > 0
    with Up(tmp_path, "resumed", "--resume", str(run_dir), "--json") as up:
        code = up.wait(240)
        assert code == 0, up.stderr()[-3000:]
        assert not up.left()
    out = json.loads(up.stdout())
    assert "interrupted" not in out and out["resumes"][0]["at_s"] == pytest.approx(first["seconds"], abs=2.0)
    # The resumed run's report keeps how it was stopped before: the stopped run's interruption, then resumed.
    assert out["interruptions"] == [first["interrupted"]]
    assert f"| interruptions | SIGTERM at {first['interrupted']['at_s']:.0f}/30 s, then resumed |" in (
        (run_dir / "report.md").read_text()
    )
    # Everything the stopped run stored (and so acknowledged) is in the resumed one's store, exactly once.
    assert out["tuples_received"] >= first["tuples_received"] + acked(out)
    # A batch whose ack comes later than the actor's resend timeout (a loaded learner fitting phase 1) is sent again
    # and dropped by the ledger as a duplicate: counted, never stored twice; no sequence is missing.
    assert out["gaps"] == 0 and out["seconds"] >= 30
    assert out["policy_versions"]["increasing"] and out["policy_versions"]["first"] > first["policy_version"]


def test_a_secure_run_stopped_mid_training_resumes_over_tls_and_trains_only_what_was_left(tmp_path: Path) -> None:
    run_dir = tmp_path / "r"
    flags = [*SMALL, "--secure", "--duration=40", "--learner-min-tuples=5000", "--learner-final-eval-trials=20"]
    with Up(tmp_path, "first", *flags, "--runs", str(tmp_path), "--run-id", "r") as up:
        wait_for(lambda: checkpoint_version(run_dir) >= 1, 120, "a checkpointed policy")
        up.send(signal.SIGTERM)
        first = assert_stopped(up, run_dir, signal.SIGTERM, learner="finished")
    stopped = first["interrupted"]["at_s"]
    # The run clock stops with training: the wind-down (the final evaluation) is not counted as training.
    assert stopped == pytest.approx(first["seconds"], abs=0.1) and stopped < 40 - 5, first["interrupted"]
    with Up(tmp_path, "resumed", "--resume", str(run_dir), "--json") as up:
        code = up.wait(240)
        assert code == 0, up.stderr()[-3000:]
        assert not up.left()
    out = json.loads(up.stdout())
    assert out["endpoint"].startswith("tls/") and out["config"]["secure"] is True
    assert out["resumes"][0]["at_s"] == pytest.approx(stopped, abs=0.1)
    assert 40 <= out["seconds"] < 40 + 3  # it trained what was left, then stopped
    assert out["tuples_received"] >= first["tuples_received"] + acked(out) and out["gaps"] == 0
    assert out["policy_versions"]["increasing"] and out["policy_versions"]["first"] > first["policy_version"]
    assert out["rejected"] == 0 and out["refused_tokens"] == 0


def test_ctrl_c_twice_kills_the_actors_and_the_learner_reports_after_its_checkpoint_unscored(tmp_path: Path) -> None:
    run_dir = tmp_path / "r"
    # Unpaced actors: a paced one resting with every batch acknowledged stops at once on the first Ctrl-C, before
    # the second could kill it, and this test is about the second.
    flags = [*SMALL, "--actor-max-tuples-per-s=none", "--duration=60", "--learner-min-tuples=5000"]
    flags += ["--runs", str(tmp_path), "--run-id", "r"]
    with Up(tmp_path, "up", *flags) as up:
        wait_for(lambda: checkpoint_version(run_dir) >= 1, 120, "a checkpointed policy")
        landed = (run_dir / "checkpoint.npz").stat().st_mtime_ns
        wait_for(lambda: (run_dir / "checkpoint.npz").stat().st_mtime_ns != landed, 30, "the next checkpoint")
        up.send(signal.SIGINT)
        up.send(signal.SIGINT)
        out = assert_stopped(up, run_dir, signal.SIGINT, learner="finished")
    assert out["interrupted"]["signals"] == 2 and "killed actor-0, actor-1" in up.stderr()
    assert "the learner skips its final evaluation" in up.stderr()
    # The second stop cuts the scoring, never the checkpoint or the policy file.
    assert "final evaluation skipped" in (run_dir / "learner.log").read_text()
    assert out["final_coverage_mean"] is None and (run_dir / "policy.npz").exists()
    assert out["policy_version"] >= 1 and out["saved"]["version"] == out["policy_version"]


def test_three_signals_kill_everything_and_the_report_comes_from_the_checkpoint(tmp_path: Path) -> None:
    run_dir = tmp_path / "r"
    flags = [*SMALL, "--duration=60", "--learner-min-tuples=5000", "--runs", str(tmp_path), "--run-id", "r"]
    with Up(tmp_path, "up", *flags) as up:
        wait_for(lambda: checkpoint_version(run_dir) >= 1, 120, "a checkpointed policy")
        saved = checkpoint_version(run_dir)
        # A learner that hangs: the second signal (which makes a live one skip its scoring) cannot end it, the third
        # kills it.
        learner = next(p for p in up.seen.values() if "learner" in p.cmdline())
        learner.suspend()
        for sig in (signal.SIGHUP, signal.SIGTERM, signal.SIGTERM):
            up.send(sig)
        out = assert_stopped(up, run_dir, signal.SIGHUP, learner="killed")
    assert out["policy_version"] >= saved and out["final_coverage_mean"] is None
    assert "result so far: policy version" in up.stdout() and (run_dir / "policy.npz").exists()


def test_children_die_with_up_when_it_is_killed(tmp_path: Path) -> None:
    """SIGKILL leaves ``up`` no say: its children get the parent-death signal (SIGTERM) and wind down by themselves."""
    run_dir = tmp_path / "r"
    flags = [*SMALL, "--duration=60", "--learner-min-tuples=5000", "--runs", str(tmp_path), "--run-id", "r"]
    with Up(tmp_path, "up", *flags) as up:
        wait_for(lambda: stored(run_dir) > 0 and len(up.seen) >= 3, 120, "a checkpoint holding experience")
        up.proc.kill()
        assert up.wait(10) == -signal.SIGKILL
        wait_for(lambda: not up.left(), 90, "the orphaned children to wind down")
    assert report(run_dir)["tuples_received"] >= stored(run_dir) > 0  # the learner's own clean stop


def test_sigterm_to_a_serial_run_winds_it_down_to_its_report_too(tmp_path: Path) -> None:
    run_dir = tmp_path / "r"
    flags = [*SMALL, "--serial", "--duration=60", "--learner-min-tuples=5000", "--runs", str(tmp_path), "--run-id", "r"]
    with Up(tmp_path, "up", *flags) as up:
        wait_for(lambda: stored(run_dir) > 0, 120, "a checkpoint holding experience")
        up.send(signal.SIGTERM)
        code = up.wait(180)
    assert code == 143, up.stderr()[-3000:]
    out = report(run_dir)
    assert out["interrupted"]["signal"] == "SIGTERM" and out["interrupted"]["learner"] == "finished"
    assert out["tuples_received"] >= stored(run_dir) > 0 and (run_dir / "report.md").exists()
    assert f"ennc-ql up --resume {run_dir}" in up.stdout()
