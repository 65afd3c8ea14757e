"""End-to-end tests: real ``ennc-ql`` processes (loopback, compose topology, network namespaces, benchmarks).

Shared here: :class:`Processes`, the child processes of one test (the library's start-up skeleton,
:class:`tools.cluster.Children`), each with its stdout and stderr in files, all stopped and reaped when the ``with``
block ends, whatever happened::

    with Processes(tmp_path) as procs:
        procs.start("router", ennc_ql("router", "--listen", endpoint))
        learner = procs.start("learner", ennc_ql("learner", ...))
        report = procs.json_result("learner", timeout=90)
"""

from __future__ import annotations

import json
import signal
import subprocess
import time
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from tools.cluster import Children, ennc_ql_argv

# Budgets of the short cluster runs: small enough for a first policy within seconds. Neither has a duration: the
# learner loads torch and fits while the actors run, which on cores shared with other tests took from 10 s to over
# 30 s, so :meth:`Processes.stop_after_first_policy` stops them once every actor adopted a policy, the actors first.
LEARNER_BUDGET = [
    "--min-tuples=5000",
    "--phase1-max-patterns=300",
    "--phase1-n-cycles=10",
    "--phase1-seed-prototypes=32",  # the default 512 seeds take the first fit 10-16 s on loaded cores
    "--phase1-max-iterations=1",
    "--broadcast-interval=1",
    "--checkpoint-interval=1",
    "--eval-interval=1000",
    "--eval-trials=1",
    "--final-eval-trials=2",
    "--json",
]
ACTOR_PACE = "10000"
"""Tuples per second each end-to-end actor is paced to (``--max-tuples-per-s``). Unpaced, two actors kept both cores
busy for their whole run, so every test's learner and the other worker's test waited for a core; what these tests
check (acks, resumes, supervision, signals) does not depend on the volume."""
ACTOR_BUDGET = ["--arenas=16", "--json", "--batch-size=1024", "--flush-timeout=30", f"--max-tuples-per-s={ACTOR_PACE}"]
FIRST_POLICY = "adopted policy version"
"""What an actor logs (at INFO) when it adopts its first policy."""


ennc_ql = ennc_ql_argv
"""The command line of ``ennc-ql ARGV`` with this interpreter."""


class Processes:
    """Child processes of one test, by name, on the library's :class:`~tools.cluster.Children`: each one's stderr in
    ``<name>.log``, its stdout in ``<name>.1.out``; ``close()`` stops and reaps every one still running."""

    def __init__(self, log_dir: Path) -> None:
        self.children = Children(log_dir, keep_stdout=True, grace=10.0)
        self.procs = self.children.procs

    def start(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        return self.children.start(name, argv)

    def log_tail(self, name: str, lines: int = 25) -> str:
        return f"--- {name} stderr (last {lines} lines) ---\n" + self.children.tail(name, lines)

    def wait(self, name: str, timeout: float) -> int:
        """Wait for ``name`` to exit by itself; its exit code (the test fails with its log on a timeout)."""
        try:
            return self.procs[name].wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{name} still running after {timeout:.0f} s\n{self.log_tail(name)}") from None

    def wait_for_log(self, name: str, text: str, timeout: float) -> None:
        """Wait until ``name``'s stderr holds ``text`` (the test fails with its log if it exits or times out first)."""
        deadline = time.monotonic() + timeout
        log = self.children.log_dir / f"{name}.log"
        while text not in log.read_text(errors="replace"):
            if self.procs[name].poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"{name} never logged {text!r}\n{self.log_tail(name)}")
            time.sleep(0.2)

    def stop_after_first_policy(
        self, actors: list[str], learner: str = "learner", timeout: float = 120.0
    ) -> tuple[list[dict[str, Any]], dict[str, Any]]:
        """Once every actor adopted a policy: SIGTERM the actors, then the learner; their JSON results (exit 0).
        The actors stop first, flushing their outboxes, so all they sent is in the learner's report."""
        for name in actors:
            self.wait_for_log(name, FIRST_POLICY, timeout)
        for name in actors:
            self.procs[name].send_signal(signal.SIGTERM)
        results = [self.json_result(name, timeout=90) for name in actors]
        self.procs[learner].send_signal(signal.SIGTERM)
        return results, self.json_result(learner, timeout=90)

    def json_result(self, name: str, timeout: float) -> dict[str, Any]:
        """Wait for ``name`` to exit 0 and return the JSON object it printed last (``--json``)."""
        code = self.wait(name, timeout)
        assert code == 0, f"{name} exited with {code}\n{self.log_tail(name)}"
        lines = self.children.stdout(name).read_text().strip().splitlines()
        assert lines, f"{name} printed nothing\n{self.log_tail(name)}"
        result: dict[str, Any] = json.loads(lines[-1])
        return result

    def close(self) -> None:
        """SIGTERM what still runs, SIGKILL what ignores it for 10 s, and reap everything."""
        self.children.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
