"""``ennc-ql up --secure`` supervises every child: the learner SIGKILLed just after a checkpoint landed comes back by
itself (``--resume auto``) and the run ends with its report, the restart counted, versions strictly increasing and
tuples stored exactly once; a killed actor and a killed router are restarted too (one run, all three faults). A
learner that cannot resume (a corrupt checkpoint) is given up after the limit, with the reason in one message."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from actors.config import ActorConfig
from learner.checkpoint import VersionMark
from learner.config import LearnerConfig
from monitor import Sink
from tests.e2e import ACTOR_PACE, ennc_ql
from tests.e2e.cluster import checkpoint_version, wait_for
from tools.cluster import LaunchError, Monitoring, run_processes
from tools.config import dump_config

pytestmark = pytest.mark.slow

SMALL = [
    "--actors=2",
    "--actor-arenas=16",
    f"--actor-max-tuples-per-s={ACTOR_PACE}",
    "--actor-batch-size=1024",
    "--learner-min-tuples=5000",
    "--learner-phase1-max-patterns=300",
    "--learner-phase1-n-cycles=10",
    "--learner-phase1-seed-prototypes=32",  # the default 512 seeds take the first fit 10-16 s on loaded cores
    "--learner-phase1-max-iterations=1",
    "--learner-eval-interval=1000",
    "--learner-eval-trials=1",
    "--learner-final-eval-trials=2",
    "--learner-margin-trials=2",  # the default 300 validation trials x 7 margins take a wind-down 20-60 s
    "--rerun=off",
    "--json",
]


def child_pid(config: Path, timeout: float = 120.0) -> int:
    """The pid of the child of ``up`` started with the configuration file ``config``, once it runs."""
    needle = str(config).encode()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit():
                try:
                    if needle in (entry / "cmdline").read_bytes():
                        return int(entry.name)
                except OSError:
                    continue
        time.sleep(0.2)
    raise AssertionError(f"no process with {config} appeared")


def wait_for_log(path: Path, text: str, timeout: float = 120.0, count: int = 1) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and path.read_text(errors="replace").count(text) >= count:
            return
        time.sleep(0.2)
    raise AssertionError(f"{text!r} never appeared in {path}")


def kill_learner_after_a_checkpoint(run_dir: Path) -> int:
    """SIGKILL the learner just after a checkpoint holding a policy landed, once versions went out that it does not
    hold (the most unsaved state); the highest version it broadcast."""
    wait_for(lambda: checkpoint_version(run_dir) >= 1, 120, "a checkpointed policy")
    landed = (run_dir / "checkpoint.npz").stat().st_mtime_ns
    wait_for(lambda: (run_dir / "checkpoint.npz").stat().st_mtime_ns != landed, 30, "the next checkpoint")
    saved = checkpoint_version(run_dir)
    wait_for(lambda: VersionMark(run_dir).load() > saved, 30, "a broadcast after the checkpoint")
    os.kill(child_pid(run_dir / "learner.toml"), signal.SIGKILL)
    return VersionMark(run_dir).load()


def test_a_killed_learner_actor_and_router_come_back_and_the_run_ends_exactly(tmp_path: Path) -> None:
    run_dir, err_path = tmp_path / "sup", tmp_path / "up.err"
    # 75 s, not 45: a fresh clone compiles every kernel on loaded cores, and the first checkpointed policy came at 43 s
    # once, leaving no run to kill the actor and router in.
    argv = ennc_ql("up", "--secure", "--duration=75", *SMALL, f"--runs={tmp_path}", "--run-id=sup")
    with open(err_path, "w") as err_file:
        up = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=err_file, text=True)
        try:
            killed_at = kill_learner_after_a_checkpoint(run_dir)
            wait_for_log(err_path, "learner exited with status -9; restarting in 1 s")
            wait_for_log(run_dir / "learner.log", "resumed from")
            os.kill(child_pid(run_dir / "actor-0.toml"), signal.SIGKILL)
            wait_for_log(err_path, "actor-0 exited with status -9; restarting in 1 s")
            # The restarted actor is a new incarnation under the same id, with its own log lines.
            wait_for_log(run_dir / "actor-0.log", "incarnation", count=2)
            # The router: its clients (learner, two actors, up's own observer) authenticate to the new one.
            router_log = run_dir / "router.log"
            wait_for_log(router_log, " connected", count=4)
            connected = router_log.read_text().count(" connected")
            os.kill(child_pid(run_dir / "secure" / "router.json5"), signal.SIGKILL)
            wait_for_log(err_path, "router exited with status -9; restarting in 1 s")
            wait_for_log(router_log, " connected", count=connected + 4)
            out, _ = up.communicate(timeout=240)
        finally:
            if up.poll() is None:
                up.kill()
                up.wait()
    assert up.returncode == 0, err_path.read_text()[-3000:]
    report = json.loads(out)
    assert json.loads((run_dir / "report.json").read_text())["policy_version"] == report["policy_version"]
    # The learner came back once, resumed from its checkpoint, its first broadcast above every version it had sent.
    [restart] = report["learner_restarts"]
    assert restart["status"] == -9 and restart["delay_s"] == 1 and restart["back_in_s"] > 0
    [resume] = report["resumes"]
    assert resume["policy_version"] > killed_at
    assert report["actor_restarts"] == {"actor-0": 1, "router": 1}
    # Versions strictly increasing on the wire across the restart, up to the final one.
    versions = report["policy_versions"]
    assert versions["increasing"] and versions["last"] == report["policy_version"] > killed_at
    # Exactly once: actor-1 stopped before the learner's end and every tuple it sent is stored once, acknowledged.
    # actor-0's first incarnation died with what it held; its second sent all it said, and nothing is missing.
    assert report["gaps"] == 0
    sent = report["actors_sent"]
    assert sent["actor-1"] == {
        "incarnations": 1,
        "reported": 1,
        "tuples_sent": report["tuples_by_actor"]["actor-1"],
        "tuples_acked": report["tuples_by_actor"]["actor-1"],
    }
    assert sent["actor-0"]["incarnations"] == 2 and sent["actor-0"]["reported"] == 1
    assert report["tuples_by_actor"]["actor-0"] > sent["actor-0"]["tuples_sent"] == sent["actor-0"]["tuples_acked"]
    assert report["final_coverage_mean"] is not None


def test_a_learner_that_cannot_resume_is_given_up_after_the_limit(tmp_path: Path) -> None:
    """A run resumed on a corrupt checkpoint (a requeued job's first start): the learner fails, is restarted once
    (the limit here), fails again and the run ends with a message naming the cause."""
    run_dir = tmp_path / "bad"
    run_dir.mkdir()
    (run_dir / "checkpoint.npz").write_bytes(b"not a checkpoint")
    learner = LearnerConfig(duration=30.0, min_tuples=5000)
    actor = ActorConfig(actor_id="actor-0", arenas=16, flush_timeout=1.0)
    for name, config in (("learner.toml", learner), ("actor-0.toml", actor)):
        (run_dir / name).write_text(dump_config(config))
    monitoring = Monitoring(Sink("off"), "bad", run_dir)
    with pytest.raises(LaunchError) as failure:
        run_processes(learner, [actor], run_dir, monitoring, namespace="run-bad", resume=True, max_restarts=1)
    message = str(failure.value)
    assert message.startswith("the learner exited with status 2 2 times in a row (1 restarts with --resume auto)")
    assert f"unreadable checkpoint {run_dir / 'checkpoint.npz'}" in message
    log = (run_dir / "learner.log").read_text()
    assert log.count("ennc-ql learner: error: --resume: unreadable checkpoint") == 2
