"""The process topology: the learner and the actors as OS processes (the same commands a multi-machine run uses),
started from their configuration files in the run folder, watched and supervised until the learner exits::

    endpoint, restarts = run_processes(learner, actors, run_dir, monitoring, namespace="run-x", secure=False)
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

from actors.config import ActorConfig
from ennc_ql.cluster.children import ACTOR_NICENESS, Children, Supervisor, ennc_ql_argv, log_tail
from ennc_ql.cluster.endpoints import Endpoints, make_endpoints
from ennc_ql.cluster.recording import Monitoring
from ennc_ql.progress import ProgressBar
from learner.config import LearnerConfig
from learner.report import LearnerStatus
from protocol import KeySpace, Status, ZenohTransport
from protocol.security import OBSERVER, ROUTER

log = logging.getLogger(__name__)

LEARNER_STOP_S = 60.0
"""The learner's final evaluation and report, once the run is over or after SIGTERM."""


class LaunchError(RuntimeError):
    """A child of ``up`` failed in a way that ends the run (the message holds the tail of its log)."""


def run_processes(
    learner: LearnerConfig,
    actors: list[ActorConfig],
    run_dir: Path,
    monitoring: Monitoring,
    namespace: str,
    secure: bool = False,
) -> tuple[str, dict[str, int]]:
    """Spawn the learner and the actors (and, ``secure``, the router they all authenticate to) with their
    configuration files, show progress until the learner exits (restarting actors and the router if they die),
    stop the others; the endpoint they used is returned (the learner's report is in the run folder) with the
    restarts of each child. Raises :class:`LaunchError` if the learner fails."""
    ids = [a.actor_id for a in actors]
    ends = make_endpoints(run_dir, namespace, learner.learner_id, ids, router=secure, secure=secure)
    log.info("learner + %d actors on %s, %.0f s", len(actors), ends.endpoint, learner.duration or 0.0)
    children = Children(run_dir)
    supervisor = Supervisor(children)
    try:
        if secure:
            supervisor.start(ROUTER, ennc_ql_argv("router", *ends.router_flags()))
        argv = ["learner", "--config", str(run_dir / "learner.toml"), "--run-dir", str(run_dir)]
        argv += [*ends.flags(learner.learner_id), *monitoring.child_args("learner")]
        children.start("learner", ennc_ql_argv(*argv))
        for actor in ids:
            argv = ["actor", "--config", str(run_dir / f"{actor}.toml"), *ends.flags(actor)]
            supervisor.start(actor, ennc_ql_argv(*argv, *monitoring.child_args(actor)), nice=ACTOR_NICENESS)
        monitoring.start()
        _watch(ends, learner, children, supervisor, len(actors))
    finally:
        supervisor.stop_all()
        if "learner" in children.procs:
            children.stop("learner", LEARNER_STOP_S)
        children.close()
    code = children.procs["learner"].returncode
    if code != 0:
        raise LaunchError(
            f"the learner exited with status {code}; the end of {run_dir / 'learner.log'}:\n"
            + log_tail(run_dir / "learner.log")
        )
    return ends.endpoint, dict(supervisor.restarts)


def cluster_status(status: LearnerStatus) -> str:
    """The live figures of the learner's status, as the progress bar shows them."""
    coverage = "–" if status.coverage is None else f"{status.coverage:.1f}%"
    return (
        f"{'exploring' if status.policy_version == 0 else 'phase 2'}: {status.tuples_received:,} tuples "
        f"({status.tuples_per_s / 1e3:.0f} k/s), policy v{status.policy_version}, "
        f"{status.live_actors} actors, coverage {coverage}"
    )


class _LatestStatus:
    """The learner's newest Status and when it arrived, written by the transport's thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._latest: LearnerStatus | None = None
        self._received = 0.0

    def on_status(self, msg: Status) -> None:
        with self._lock:
            self._latest = LearnerStatus.from_counters(msg.counters)
            self._received = time.monotonic()

    def get(self) -> tuple[LearnerStatus | None, float]:
        """The newest status and its age in seconds."""
        with self._lock:
            return self._latest, time.monotonic() - self._received


def _watch(ends: Endpoints, learner: LearnerConfig, children: Children, supervisor: Supervisor, actors: int) -> None:
    """Show the learner's progress from its status messages until it exits, and supervise the others meanwhile.

    The bar runs on the learner's own training clock, carried forward between status messages (every 2 s) so it
    moves each second; past the duration the learner evaluates and writes its report and sends no more status.
    """
    keys = KeySpace(ends.namespace)
    duration = learner.duration or 0.0
    latest = _LatestStatus()
    with ProgressBar("up", total=duration, unit="s") as bar, ZenohTransport.open(ends.session(OBSERVER), keys) as t:
        t.subscribe(keys.status(learner.learner_id), Status, latest.on_status)
        bar.show(status=f"starting the learner and {actors} actor(s)")
        version: int = 0
        coverage: float | None = None
        while "learner" in children.running():
            time.sleep(1.0)
            for message in supervisor.check():
                bar.mark(message)
            status, age = latest.get()
            if status is None:
                continue
            n = min(status.elapsed + age, duration)
            _mark_events(bar, status, n, version, coverage)
            version, coverage = status.policy_version, status.coverage
            bar.show(n, "training over: final evaluation and report" if n >= duration else cluster_status(status))


def _mark_events(bar: ProgressBar, status: LearnerStatus, n: float, version: int, coverage: float | None) -> None:
    """The lines the bar leaves behind: the first policy, and each new evaluation."""
    if version == 0 and status.policy_version > 0:
        bar.mark(f"phase 1 done: policy v{status.policy_version} sent, phase 2 starts", n)
    if status.coverage is not None and status.coverage != coverage:
        bar.mark(f"evaluation: policy v{status.policy_version} observes {status.coverage:.1f}% of targets", n)
