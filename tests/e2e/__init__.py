"""End-to-end tests: real ``ennc-ql`` processes (loopback, compose topology, network namespaces, benchmarks).

Shared here: :class:`Processes`, the child processes of one test, each with its stdout and stderr in files, all
stopped and reaped when the ``with`` block ends, whatever happened::

    with Processes(tmp_path) as procs:
        procs.start("router", ennc_ql("router", "--listen", endpoint))
        learner = procs.start("learner", ennc_ql("learner", ...))
        report = procs.json_result("learner", timeout=90)
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import TracebackType
from typing import Any, Self

# Budgets of the short cluster runs: small enough for a first policy within seconds on two busy cores, and the
# actors stop ten seconds before the learner does, so all they sent is acknowledged and in the learner's report.
# The actors start at once while the learner loads torch and scikit-learn (several seconds on loaded cores), so the
# actors' time leaves room for that before the first policy.
LEARNER_BUDGET = [
    "--duration=34",
    "--min-tuples=5000",
    "--phase1-max-patterns=300",
    "--phase1-n-cycles=10",
    "--broadcast-interval=1",
    "--checkpoint-interval=1",
    "--eval-interval=1000",
    "--eval-trials=1",
    "--final-eval-trials=2",
    "--json",
]
ACTOR_BUDGET = ["--duration=24", "--arenas=16", "--json", "--batch-size=1024", "--flush-timeout=30"]


def ennc_ql(*argv: str) -> list[str]:
    """The command line of ``ennc-ql ARGV`` with this interpreter (no reliance on PATH or the console script)."""
    return [sys.executable, "-m", "ennc_ql.cli", *argv]


class Processes:
    """Child processes of one test, by name; ``close()`` stops and reaps every one still running."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        with open(self.log_dir / f"{name}.out", "wb") as out, open(self.log_dir / f"{name}.log", "wb") as err:
            proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err)
        self.procs[name] = proc
        return proc

    def log_tail(self, name: str, lines: int = 25) -> str:
        text = (self.log_dir / f"{name}.log").read_text(errors="replace")
        return f"--- {name} stderr (last {lines} lines) ---\n" + "\n".join(text.splitlines()[-lines:])

    def wait(self, name: str, timeout: float) -> int:
        """Wait for ``name`` to exit by itself; its exit code (the test fails with its log on a timeout)."""
        try:
            return self.procs[name].wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{name} still running after {timeout:.0f} s\n{self.log_tail(name)}") from None

    def json_result(self, name: str, timeout: float) -> dict[str, Any]:
        """Wait for ``name`` to exit 0 and return the JSON object it printed last (``--json``)."""
        code = self.wait(name, timeout)
        assert code == 0, f"{name} exited with {code}\n{self.log_tail(name)}"
        lines = (self.log_dir / f"{name}.out").read_text().strip().splitlines()
        assert lines, f"{name} printed nothing\n{self.log_tail(name)}"
        result: dict[str, Any] = json.loads(lines[-1])
        return result

    def close(self) -> None:
        """SIGTERM what still runs, SIGKILL what ignores it for 10 s, and reap everything."""
        running = [p for p in self.procs.values() if p.poll() is None]
        for proc in running:
            proc.terminate()
        for proc in running:
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
