"""The process topology: the learner and the actors as OS processes (the same commands a multi-machine run uses),
started from their configuration files in the run folder, watched and supervised until the learner is done::

    run = run_processes(learner, actors, run_dir, monitoring, namespace="run-x", secure=False)
    run.supervision(report)                                   # endpoint, restarts, what the actors sent, ...

Every child is supervised: an actor or the router that dies is started again, and so is the learner, with
``--resume auto`` (it continues from its checkpoint); a child failing ``max_restarts`` times in a row is given up,
and a learner given up ends the run with :class:`LaunchError`. A few seconds before the learner's training time is
over the actors stop and hand in their outboxes, so everything they sent is stored and acknowledged before the
learner's final checkpoint, and the report can set what each actor sent beside what the learner stored.

Where each child runs is a :class:`Placement`: this machine (``up``), or a node of a SLURM allocation
(``tools.slurm``), whose children are ``srun`` job steps.
"""

from __future__ import annotations

import itertools
import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from actors.config import ActorConfig
from learner.config import LearnerConfig
from learner.report import LearnerReport, LearnerStatus
from protocol import KeySpace, PolicyUpdate, Status, ZenohTransport
from protocol.security import OBSERVER, ROUTER
from tools.cluster.children import ACTOR_NICENESS, Children, Restart, Supervisor, ennc_ql_argv, log_tail
from tools.cluster.endpoints import LOOPBACK, Endpoints, make_endpoints
from tools.cluster.recording import Monitoring
from tools.cluster.report import LearnerRestart, PolicyVersions, Supervision
from tools.progress import ProgressBar
from tools.system import Interrupts

log = logging.getLogger(__name__)

LEARNER = "learner"
"""The learner child's name (its log is ``learner.log``)."""
LEARNER_STOP_S = 60.0
"""The learner's final evaluation and report, once the run is over or after the stop signal."""
ACTOR_STOP_EXTRA_S = 5.0
"""Seconds an actor gets beyond its own flush timeout to stop, before it is killed."""


class LaunchError(RuntimeError):
    """A child of the run failed in a way that ends the run (the message holds the tail of its log)."""


@dataclass(frozen=True, slots=True)
class Placement:
    """Where a run's children start: on this machine, with the listener on loopback."""

    host: str = LOOPBACK
    """The address the listener (the router, or the learner peer-to-peer) binds and the others dial."""
    names: tuple[str, ...] = ()
    """Other names of ``host`` (the router's certificate holds them)."""
    stop_signal: int = signal.SIGTERM
    """What asks a child to wind down."""
    owns_children: bool = True
    """The children are this process's own: in a process group of their own, and they die with it."""

    def command(self, name: str, argv: list[str]) -> list[str]:
        """The command line that runs child ``name``'s ``argv`` where it belongs."""
        return argv


@dataclass(frozen=True, slots=True)
class ProcessRun:
    """What the supervision of a run saw, beside the learner's own report."""

    endpoint: str
    started: float
    """Wall time the run's children were started."""
    restarts: dict[str, int]
    """Restarts of each child."""
    events: list[Restart]
    actors_sent: dict[str, dict[str, int]]
    """Per actor: incarnations, how many reported at their end, and the tuples those sent and had acknowledged."""
    first_policy_s: float | None
    """Seconds from the start to the first policy seen on the wire."""
    versions: list[int]
    """Every policy version seen on the wire, in arrival order."""

    def supervision(self, report: LearnerReport) -> Supervision:
        """What the supervision adds to the learner's report: the restarts of the learner (each with the seconds from
        its end being noticed to the resumed learner's first broadcast) and of the other children, what each actor
        sent, when the first policy came and whether the versions seen only increased."""
        resumes: list[dict[str, Any]] = [r for r in report.resumes if r.get("wall_time", 0.0) >= self.started]
        learner: list[LearnerRestart] = []
        for i, event in enumerate(e for e in self.events if e.name == LEARNER):
            back = resumes[i]["wall_time"] - event.noticed_at if i < len(resumes) else None
            back_in = None if back is None else round(back, 2)
            learner.append(LearnerRestart(event.status, event.ran_s, event.delay_s, back_in))
        versions = self.versions
        return Supervision(
            endpoint=self.endpoint,
            actor_restarts={name: n for name, n in self.restarts.items() if name != LEARNER},
            learner_restarts=tuple(learner),
            actors_sent=self.actors_sent,
            first_policy_s=self.first_policy_s,
            policy_versions=PolicyVersions(
                seen=len(versions),
                first=versions[0] if versions else None,
                last=versions[-1] if versions else None,
                increasing=all(a < b for a, b in itertools.pairwise(versions)),
            ),
        )


def run_processes(
    learner: LearnerConfig,
    actors: list[ActorConfig],
    run_dir: Path,
    monitoring: Monitoring,
    namespace: str,
    secure: bool = False,
    *,
    placement: Placement | None = None,
    resume: bool = False,
    max_restarts: int = 3,
    stop: threading.Event | None = None,
    interrupts: Interrupts | None = None,
) -> ProcessRun:
    """Spawn the learner and the actors (and, ``secure``, the router they all authenticate to) with their
    configuration files, show progress until the learner is done (or ``stop`` is set: then the children are stopped,
    the learner with time for its checkpoint and report), supervising every child, then stop the others.
    ``resume``: the learner's first start already resumes from a checkpoint if there is one (a requeued job).
    ``interrupts``: the launcher's signals; the first stops the run (as ``stop``), the second kills the actors, the
    third the learner and the router; the children are waited for whatever comes. Raises :class:`LaunchError` if
    the learner is given up."""
    where = placement or Placement()
    ids = [a.actor_id for a in actors]
    ends = make_endpoints(
        run_dir, namespace, learner.learner_id, ids, router=secure, secure=secure, host=where.host, hosts=where.names
    )
    log.info("learner + %d actors on %s, %.0f s", len(actors), ends.endpoint, learner.duration or 0.0)
    # The actors' stdout: what each incarnation sent, printed as it ends (--json).
    children = Children(run_dir, keep_stdout=set(ids), stop_signal=where.stop_signal, own_group=where.owns_children)
    supervisor = Supervisor(children, max_restarts=max_restarts)
    if interrupts is not None:
        stop = interrupts.stop
        interrupts.escalate(
            lambda: _sooner(children, ids),
            lambda: f"killed {', '.join(children.kill_now({LEARNER, ROUTER})) or 'nothing'}",
        )
    actor_stop_s = max((a.flush_timeout for a in actors), default=0.0) + ACTOR_STOP_EXTRA_S
    started = time.time()
    policies = _Policies()
    try:
        _start(supervisor, where, ends, learner.learner_id, ids, run_dir, monitoring, secure=secure, resume=resume)
        monitoring.start()
        _watch(ends, learner, supervisor, ids, policies, actor_stop_s, stop or threading.Event())
    finally:
        supervisor.stop(ids, actor_stop_s)
        supervisor.stop([LEARNER], LEARNER_STOP_S)
        supervisor.stop_all()
        children.close()
    if LEARNER in supervisor.given_up:
        raise LaunchError(
            f"the learner exited with status {supervisor.given_up[LEARNER]} {max_restarts + 1} times in a row "
            f"({max_restarts} restarts with --resume auto); given up. The end of {run_dir / 'learner.log'}:\n"
            + log_tail(run_dir / "learner.log")
        )
    first = policies.first()
    return ProcessRun(
        endpoint=ends.endpoint,
        started=started,
        restarts=dict(supervisor.restarts),
        events=list(supervisor.events),
        actors_sent={actor: _sent(children, actor) for actor in ids},
        first_policy_s=None if first is None else round(first - started, 2),
        versions=policies.versions(),
    )


def _start(
    supervisor: Supervisor,
    where: Placement,
    ends: Endpoints,
    learner_id: str,
    ids: list[str],
    run_dir: Path,
    monitoring: Monitoring,
    *,
    secure: bool,
    resume: bool,
) -> None:
    """Start the router (``secure``), the learner (resuming at once with ``resume``; always when restarted) and the
    actors, each from its configuration file in ``run_dir``."""
    if secure:
        supervisor.start(ROUTER, where.command(ROUTER, ennc_ql_argv("router", *ends.router_flags())))
    argv = ["learner", "--config", str(run_dir / "learner.toml"), "--run-dir", str(run_dir)]
    fresh = ennc_ql_argv(*argv, *ends.flags(learner_id), *monitoring.child_args(LEARNER))
    resumed = where.command(LEARNER, [*fresh, "--resume", "auto"])
    supervisor.start(LEARNER, resumed if resume else where.command(LEARNER, fresh), restart_argv=resumed)
    for actor in ids:
        argv = ["actor", "--config", str(run_dir / f"{actor}.toml"), *ends.flags(actor), "--json"]
        command = where.command(actor, ennc_ql_argv(*argv, *monitoring.child_args(actor, relay=True)))
        supervisor.start(actor, command, nice=ACTOR_NICENESS)


def _sent(children: Children, actor: str) -> dict[str, int]:
    """What an actor's incarnations printed at their end (``--json``): a killed one printed nothing."""
    finals = []
    for k in range(1, children.incarnations(actor) + 1):
        lines = children.stdout(actor, k).read_text(errors="replace").strip().splitlines()
        if lines:
            try:
                finals.append(json.loads(lines[-1]))
            except ValueError:
                continue
    return {
        "incarnations": children.incarnations(actor),
        "reported": len(finals),
        "tuples_sent": sum(int(f["tuples_sent"]) for f in finals),
        "tuples_acked": sum(int(f["tuples_acked"]) for f in finals),
    }


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


class _Policies:
    """The policy versions seen on the wire and when the first came, written by the transport's thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._versions: list[int] = []
        self._first: float | None = None

    def on_policy(self, update: PolicyUpdate) -> None:
        with self._lock:
            self._versions.append(int(update.version))
            if self._first is None:
                self._first = time.time()

    def versions(self) -> list[int]:
        with self._lock:
            return list(self._versions)

    def first(self) -> float | None:
        with self._lock:
            return self._first


def _watch(
    ends: Endpoints,
    learner: LearnerConfig,
    supervisor: Supervisor,
    actors: list[str],
    policies: _Policies,
    actor_stop_s: float,
    stop: threading.Event,
) -> None:
    """Show the learner's progress from its status messages until it is done, supervising the children meanwhile,
    and stop the actors a few seconds before its training time is over.

    The bar runs on the learner's own training clock, carried forward between status messages (every 2 s) so it
    moves each second; past the duration its clock stands still while it scores (its statuses carry the share done). A
    status older than two of its intervals is not carried forward: the learner is down (or restarting), its clock
    stands still.
    """
    keys = KeySpace(ends.namespace)
    duration = learner.duration or 0.0
    # The actors' last messages need a checkpoint to be acknowledged (two intervals to be sure of a whole one), and
    # the status that tells the time is up to one interval old.
    lead = 2 * learner.checkpoint_interval + learner.status_interval + 2.0
    latest = _LatestStatus()
    with ProgressBar("up", total=duration, unit="s") as bar, ZenohTransport.open(ends.session(OBSERVER), keys) as t:
        t.subscribe(keys.status(learner.learner_id), Status, latest.on_status)
        t.subscribe(keys.policy(), PolicyUpdate, policies.on_policy)
        bar.show(status=f"starting the learner and {len(actors)} actor(s)")
        version: int = 0
        coverage: float | None = None
        actors_running = True
        shown = 0.0  # the clock as shown: a status that arrives late carries it back, and a clock never runs back

        def clock(carry: bool = True) -> float:
            """The learner's training clock as shown: its last status, carried forward by the status's age while the
            learner trains (``carry``), never back."""
            nonlocal shown
            status, age = latest.get()
            if status is not None:
                fresh = carry and age <= 2 * learner.status_interval
                shown = max(shown, min(status.elapsed + (age if fresh else 0.0), duration))
            return shown

        while LEARNER not in supervisor.finished and LEARNER not in supervisor.given_up:
            if stop.wait(1.0):
                _wind_down(bar, latest, supervisor, actors if actors_running else [], actor_stop_s, clock)
                return
            for message in supervisor.check():
                bar.mark(message)
            status, age = latest.get()
            if status is None:
                continue
            fresh = age <= 2 * learner.status_interval
            n = clock()
            if actors_running and fresh and n >= duration - lead:
                bar.mark("training ends: the actors stop and hand in their outboxes", n)
                supervisor.stop(actors, actor_stop_s)
                actors_running = False
            _mark_events(bar, status, n, version, coverage)
            version, coverage = status.policy_version, status.coverage
            bar.show(n, _scoring(status) if n >= duration else cluster_status(status))


def _sooner(children: Children, actors: list[str]) -> str:
    """A second signal's step: the actors killed (what their outboxes held is lost) and the learner told to stop
    again, which skips its final evaluation once its checkpoint is written."""
    killed = ", ".join(children.kill_now(actors)) or "no actor"
    if LEARNER in children.running():
        children.signal(LEARNER, children.stop_signal)
    return f"killed {killed}; the learner skips its final evaluation; again to kill the learner too"


def _scoring(status: LearnerStatus) -> str:
    done = "" if status.scoring is None else f" ({status.scoring:.0%})"
    return f"training over: final evaluation{done} and report"


def _wind_down(
    bar: ProgressBar,
    latest: _LatestStatus,
    supervisor: Supervisor,
    actors: list[str],
    actor_stop_s: float,
    clock: Callable[[bool], float],
) -> None:
    """Stop the actors (they hand in their outboxes), then the learner (its checkpoint, its scoring, its report), the
    bar showing each phase's seconds and the scoring's progress from the learner's statuses. The learner trains on
    while the actors hand in, so the bar's clock runs on with it until the learner is stopped: the time the report
    gives for the interruption."""
    bar.mark(
        "stopping: the actors hand in their outboxes, then the learner checkpoints, scores and reports", clock(True)
    )
    if actors:
        hand_in = "the actors hand in their outboxes"
        _phase(bar, hand_in, lambda: supervisor.stop(actors, actor_stop_s), None, lambda: clock(True))
    learner = "the learner checkpoints, scores and reports"
    _phase(bar, learner, lambda: supervisor.stop([LEARNER], LEARNER_STOP_S), latest, lambda: clock(False))
    # Off a terminal the phases' lines are rate-limited: the last line says when training stopped, as the report will.
    bar.mark("wound down: the report follows", clock(False))


def _phase(bar: ProgressBar, what: str, work: Any, latest: _LatestStatus | None, clock: Callable[[], float]) -> None:
    """``work`` (a blocking stop) on a thread of its own while the bar ticks every half second on ``clock``; its
    error raised."""
    done = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            work()
        except BaseException as exc:  # raised again below, on the launcher's thread
            errors.append(exc)
        finally:
            done.set()

    threading.Thread(target=run, name="wind-down", daemon=True).start()
    began = time.monotonic()
    while not done.wait(0.5):
        status, _ = latest.get() if latest is not None else (None, 0.0)
        scoring = "" if status is None or status.scoring is None else f", scoring {status.scoring:.0%}"
        bar.show(clock(), f"stopping: {what} ({time.monotonic() - began:.0f} s{scoring})")
    if errors:
        raise errors[0]


def _mark_events(bar: ProgressBar, status: LearnerStatus, n: float, version: int, coverage: float | None) -> None:
    """The lines the bar leaves behind: the first policy, and each new evaluation."""
    if version == 0 and status.policy_version > 0:
        bar.mark(f"phase 1 done: policy v{status.policy_version} sent, phase 2 starts", n)
    if status.coverage is not None and status.coverage != coverage:
        bar.mark(f"evaluation: policy v{status.policy_version} observes {status.coverage:.1f}% of targets", n)
