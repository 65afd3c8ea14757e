"""The local cluster as a library: one learner and N actors, as OS processes on loopback Zenoh or as objects in
this process on the in-memory bus (serial mode, for a debugger or a profiler), with the same report.

Usage::

    config = load_config(UpConfig, defaults=UP_PRESETS)
    learner, actors = child_configs(config)
    report = run_serial(learner, actors, run_dir)                        # one process
    endpoint, restarts = run_processes(learner, actors, run_dir, monitoring, namespace)  # as OS processes
"""

from __future__ import annotations

import dataclasses
import logging
import os
import subprocess
import sys
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from actors.config import ActorConfig
from algorithm.checks import require_at_least, require_known, require_positive
from ennc_ql.config import dump_config
from ennc_ql.progress import ProgressBar
from ennc_ql.system import free_port
from learner.config import LearnerConfig
from learner.report import LearnerReport, LearnerStatus
from monitor import (
    Monitor,
    RecordingError,
    Sink,
    merge_recordings,
    open_monitor,
    paths,
    summarize_recording,
)
from monitor.recordings import rerun_cli
from protocol import Status
from protocol.security import OBSERVER, ROUTER
from sim.features import DEFAULT_FORMULATION, FORMULATIONS

log = logging.getLogger(__name__)

ACTOR_NICENESS = 10
"""Actors produce experience faster than one learner digests it on a shared machine: they yield the CPU to the
learner so phase 1 and evaluations are not starved."""


FORMULATION_PARTS = ("featurizer", "reward", "act_every")
"""Fields of the learner's and the actors' configurations that override their formulation's parts: ``up`` gives
every process the one formulation it names instead."""


@dataclass(frozen=True, slots=True)
class UpConfig:
    actors: int = 2
    """Actor processes (each learns every robot's table: option 2)."""
    duration: float = 480.0
    """Seconds of training."""
    seed: int = 0
    """Run seed, given to the learner and to every actor (each derives its own stream from it and its id)."""
    formulation: str = DEFAULT_FORMULATION
    """State, reward and action set of every process, by name: shared-difference (the shared8d state, the difference
    reward, deciding every step in tests: the best formulation of the README's ablations) or paper (the paper's
    collab6d state and Eq. 2 reward, deciding once per action)."""
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    """The learner process."""
    actor: ActorConfig = field(default_factory=ActorConfig)
    """Every actor process (ids actor-0, actor-1, ...)."""

    def __post_init__(self) -> None:
        require_at_least(1, actors=self.actors)
        require_positive(duration=self.duration)
        require_known("formulation", self.formulation, FORMULATIONS)
        parts = [
            f"{role}.{name}"
            for role, process in (("learner", self.learner), ("actor", self.actor))
            for name in FORMULATION_PARTS
            if getattr(process, name, None) is not None
        ]
        if parts:
            raise ValueError(f"{', '.join(parts)}: up gives every process the formulation it names (--formulation)")
        # The learner's and the actors' own formulation is up's, so that up.toml says one thing once.
        for role in ("learner", "actor"):
            object.__setattr__(self, role, dataclasses.replace(getattr(self, role), formulation=self.formulation))


UP_PRESETS: dict[str, Any] = {
    # A 400 000-tuple store holds under a second of two actors' experience (~530 k tuples/s) and keeps the learner's
    # RSS modest.
    "learner.store_capacity": 400_000,
    # Evaluations cost CPU the actors share: every 30 s gives a 16-point learning curve in 8 minutes.
    "learner.eval_interval": 30.0,
    # Multi-threaded torch stalls on cores the actors keep busy; one thread is as fast there.
    "learner.threads": 1,
    # Two actors x 500 arenas saturate the 2-core machine without starving the learner.
    "actor.arenas": 500,
    # A second fitted iteration measured +1 to +3 points at the full budget (README, Ablations) for one more fit.
    "learner.phase1.max_iterations": 2,
}
"""What ``ennc-ql up`` sets differently from the processes' own defaults, named once."""

SET_BY_UP = (
    "learner.duration",
    "learner.seed",
    "learner.formulation",
    *(f"learner.{name}" for name in FORMULATION_PARTS),
    "actor.actor_id",
    "actor.seed",
    "actor.duration",
    "actor.formulation",
    "actor.featurizer",
    "actor.reward",
)
"""Fields ``up`` fills in itself from its own settings (no flags for them)."""


def child_configs(config: UpConfig) -> tuple[LearnerConfig, list[ActorConfig]]:
    learner = dataclasses.replace(config.learner, duration=config.duration, seed=config.seed)
    actors = [
        dataclasses.replace(config.actor, actor_id=f"actor-{i}", seed=config.seed, duration=None)
        for i in range(config.actors)
    ]
    return learner, actors


def write_configs(config: UpConfig, learner: LearnerConfig, actors: list[ActorConfig], run_dir: Path) -> None:
    """Every process's resolved configuration in the run folder: the run can be repeated exactly from them."""
    (run_dir / "up.toml").write_text(dump_config(config))
    (run_dir / "learner.toml").write_text(dump_config(learner))
    for actor in actors:
        (run_dir / f"{actor.actor_id}.toml").write_text(dump_config(actor))


# -- serial mode ------------------------------------------------------------------------------------------------------


def run_serial(learner: LearnerConfig, actors: list[ActorConfig], run_dir: Path) -> LearnerReport:
    """The learner and the actors as objects in this process on one in-memory bus, each on its own thread; ends when
    the learner's duration is over, as the process topology does."""
    from actors.actor import RobotActor
    from actors.wiring import connect as connect_actor
    from learner.service import LearnerService
    from learner.wiring import connect as connect_learner
    from protocol import InMemoryBus, InMemoryTransport

    bus = InMemoryBus()
    stop_actors = threading.Event()
    with ExitStack() as stack:
        learner_transport = stack.enter_context(InMemoryTransport(bus))
        service = LearnerService(learner_transport, learner, run_dir)
        handles = connect_learner(service, learner_transport)
        threads = []
        for config in actors:
            transport = stack.enter_context(InMemoryTransport(bus))
            actor = RobotActor(transport, config)
            handles += connect_actor(actor, transport)
            threads.append(threading.Thread(target=actor.run, args=(stop_actors,), name=config.actor_id))
        for thread in threads:
            thread.start()
        try:
            log.info(
                "serial: the learner and %d actor(s) in this process for %.0f s", len(actors), learner.duration or 0
            )
            report = service.run(threading.Event())
        finally:
            stop_actors.set()
            for thread in threads:
                thread.join()
            for handle in reversed(handles):
                handle.close()
    return report


# -- processes --------------------------------------------------------------------------------------------------------


VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where a viewer spawned by ``up`` (or its ``rerun --serve-grpc`` proxy) takes the children's streams."""


class Monitoring:
    """The Rerun side of a run: what each child is told, and what ``up`` itself starts and finishes.

    ``save`` (the default): every child saves its own part file with the run's recording id (processes cannot share
    one file) and the parts are merged into one recording at the end. ``spawn``: ``up`` starts a local viewer and
    the children stream to it. ``serve``: ``up`` starts a ``rerun --serve-grpc`` proxy on port 9876 that viewers on
    this or other machines connect to. ``connect URL``: the children stream to that viewer or proxy.
    """

    def __init__(self, sink: Sink, run_id: str, run_dir: Path) -> None:
        self.sink = sink
        self.run_id = run_id
        self.run_dir = run_dir
        self.viewer: Monitor | None = None
        self.proxy: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        if self.sink.kind == "spawn":
            self.viewer = open_monitor(self.sink, process="up", recording_id=self.run_id)
        elif self.sink.kind == "serve":
            self.proxy = subprocess.Popen(
                [*rerun_cli(), "--serve-grpc", "--port", "9876"],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            log.warning("watch with: rerun --connect rerun+http://<this host>:9876/proxy")

    def child_args(self, name: str) -> list[str]:
        kind = self.sink.kind
        if kind == "off":
            return []
        if kind == "save":
            target = str(paths.part_file(self.run_dir, name))
        else:
            target = str(self.sink.target) if kind == "connect" else VIEWER_URL
        return ["--rerun", "save" if kind == "save" else "connect", target, "--recording-id", self.run_id]

    def finish(self) -> dict[str, Any] | None:
        """Merge the part files (``save``) and summarise the recording; stop what ``start`` started."""
        if self.viewer is not None:
            self.viewer.close()
        if self.proxy is not None:
            stop_child(self.proxy, grace=5.0)
        if self.sink.kind != "save":
            return None
        parts = sorted((self.run_dir / "rerun").glob("*.rrd"))
        if not parts:
            log.warning("no Rerun part files in %s", self.run_dir / "rerun")
            return None
        try:
            summary = summarize_recording(merge_recordings(parts, Path(str(self.sink.target))))
        except RecordingError as exc:  # the run's results stand without its recording; the parts stay on disk
            log.error("could not merge the Rerun part files %s: %s", [str(p) for p in parts], exc)
            return None
        for part in parts:  # all of it is in the merged recording now
            part.unlink()
        (self.run_dir / "rerun").rmdir()
        return {k: summary[k] for k in ("path", "size_bytes", "recording_ids", "entity_paths", "rows")}


class LaunchError(RuntimeError):
    """A child of ``up`` failed in a way that ends the run (the message holds the tail of its log)."""


def log_tail(path: Path, lines: int = 15) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"


class Supervisor:
    """``up``'s restartable children (the actors, and the router of a secure run): one that exits while the run goes
    on is reported at once with the tail of its log and started again after a back-off (1, 2, 4 s, ...), at most
    ``max_restarts`` times; past that the run goes on without it, saying so. Usage (from the progress loop, once a
    second)::

        supervisor = Supervisor(run_dir, max_restarts=3)
        supervisor.start("actor-0", ["actor", "--config", ...], nice=ACTOR_NICENESS)   # for each child
        for message in supervisor.check(): ...  # what happened since the last check
        supervisor.stop_all()
    """

    def __init__(self, run_dir: Path, max_restarts: int = 3) -> None:
        self.run_dir = run_dir
        self.max_restarts = max_restarts
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.argv: dict[str, tuple[list[str], int]] = {}  # name -> (argv, niceness)
        self.restarts: dict[str, int] = {}
        self._due: dict[str, float] = {}  # name -> when to start it again

    def start(self, name: str, argv: list[str], nice: int = 0) -> None:
        self.argv[name] = (argv, nice)
        with open(self.run_dir / f"{name}.log", "a") as log_file:
            self.procs[name] = spawn_child(argv, log_file, nice=nice)

    def check(self) -> list[str]:
        messages = []
        now = time.monotonic()
        for name, proc in list(self.procs.items()):
            if proc.poll() is None or name in self._due:
                continue
            n = self.restarts.get(name, 0)
            tail = log_tail(self.run_dir / f"{name}.log")
            if n >= self.max_restarts:
                messages.append(f"{name} exited with status {proc.returncode} again; not restarted ({n} restarts)")
                log.error("%s exited with status %s; its log ends:\n%s", name, proc.returncode, tail)
                del self.procs[name]
                continue
            self._due[name] = now + 2.0**n
            messages.append(f"{name} exited with status {proc.returncode}; restarting in {2**n} s")
            log.error("%s exited with status %s; its log ends:\n%s", name, proc.returncode, tail)
        for name, due in list(self._due.items()):
            if now >= due:
                del self._due[name]
                self.restarts[name] = self.restarts.get(name, 0) + 1
                self.start(name, *self.argv[name])
        return messages

    def stop_all(self) -> None:
        # Actors first, the router last: actors flush their outboxes through it.
        for name in sorted(self.procs, key=lambda n: n == ROUTER):
            stop_child(self.procs[name], grace=10.0)


@dataclass(frozen=True, slots=True)
class Endpoints:
    """How each process of a local run joins it: zenoh flags per process, and the observer's own config."""

    learner: list[str]
    actors: dict[str, list[str]]
    observer: Any  # a zenoh.Config (zenoh is imported only once a run starts)
    shown: str
    """The endpoint as the report shows it."""
    router: list[str] | None = None
    """The router's flags, in a secure run."""


def plain_endpoints(actors: list[ActorConfig]) -> Endpoints:
    """Peer mode on a loopback port: the learner listens, every actor and the observer connect to it."""
    from protocol import zenoh_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    observer = zenoh_config(connect=[endpoint], mode="peer", multicast_scouting=False)
    return Endpoints(["--listen", endpoint], {a.actor_id: ["--connect", endpoint] for a in actors}, observer, endpoint)


def secure_endpoints(learner: LearnerConfig, actors: list[ActorConfig], run_dir: Path, namespace: str) -> Endpoints:
    """A router on a loopback TLS port, every process its client with its own certificate, password and
    access-control identity (``ennc-ql secure init``'s files, written into ``run_dir/secure``)."""
    from ennc_ql.secure import SecureSet, write_secure_set
    from protocol import zenoh_config

    port = free_port()
    spec = SecureSet(
        folder=run_dir / "secure",
        actor_ids=tuple(a.actor_id for a in actors),
        learner_id=learner.learner_id,
        namespace=namespace,
        listen=(f"tls/127.0.0.1:{port}",),
        connect=(f"tls/localhost:{port}",),
    )
    write_secure_set(spec)

    def flags(ident: str) -> list[str]:
        return ["--zenoh-config", str(spec.config(ident))]

    return Endpoints(
        flags(learner.learner_id),
        {a.actor_id: flags(a.actor_id) for a in actors},
        zenoh_config(config_file=str(spec.config(OBSERVER))),
        spec.connect[0],
        router=flags(ROUTER),
    )


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
    ends = secure_endpoints(learner, actors, run_dir, namespace) if secure else plain_endpoints(actors)
    common = ["--namespace", namespace, "--no-multicast-scouting"]
    log.info("learner + %d actors on %s, %.0f s", len(actors), ends.shown, learner.duration or 0.0)
    supervisor = Supervisor(run_dir)
    if ends.router is not None:
        supervisor.start(ROUTER, ["router", *ends.router])
    learner_argv = ["learner", "--config", str(run_dir / "learner.toml"), "--run-dir", str(run_dir)]
    learner_argv += [*ends.learner, *common, *monitoring.child_args("learner")]
    with open(run_dir / "learner.log", "w") as learner_log:
        learner_proc = spawn_child(learner_argv, learner_log)
    try:
        for config in actors:
            toml = str(run_dir / f"{config.actor_id}.toml")
            argv = ["actor", "--config", toml, *ends.actors[config.actor_id], *common]
            supervisor.start(config.actor_id, argv + monitoring.child_args(config.actor_id), nice=ACTOR_NICENESS)
        monitoring.start()
        _watch(ends.observer, namespace, learner, learner_proc, supervisor, len(actors))
    finally:
        supervisor.stop_all()
        stop_child(learner_proc, grace=60.0)
    if learner_proc.returncode != 0:
        raise LaunchError(
            f"the learner exited with status {learner_proc.returncode}; the end of {run_dir / 'learner.log'}:\n"
            + log_tail(run_dir / "learner.log")
        )
    return ends.shown, dict(supervisor.restarts)


def spawn_child(
    argv: list[str], log_file: IO[str], nice: int = 0, stdout: IO[str] | int = subprocess.DEVNULL
) -> subprocess.Popen[bytes]:
    """``ennc-ql <argv>`` as a child process with this interpreter, its stderr into ``log_file``, at ``nice``."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ennc_ql.cli", *argv],
        stdout=stdout,
        stderr=log_file,
        stdin=subprocess.DEVNULL,
    )
    if nice:
        # From here rather than a preexec_fn, which is unsafe once this process has threads (restarts happen then).
        os.setpriority(os.PRIO_PROCESS, proc.pid, nice)
    return proc


def stop_child(proc: subprocess.Popen[bytes], grace: float) -> None:
    """SIGTERM, then SIGKILL if ``proc`` is still running after ``grace`` seconds."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def cluster_status(status: LearnerStatus) -> str:
    """The live figures of the learner's status, as the progress bar shows them."""
    coverage = "–" if status.coverage < 0 else f"{status.coverage:.1f}%"
    return (
        f"{'exploring' if status.policy_version == 0 else 'phase 2'}: {status.tuples_received:,} tuples "
        f"({status.tuples_per_s / 1e3:.0f} k/s), policy v{status.policy_version}, "
        f"{status.live_actors} actors, coverage {coverage}"
    )


def _watch(
    conf: Any,
    namespace: str,
    learner: LearnerConfig,
    proc: subprocess.Popen[bytes],
    supervisor: Supervisor,
    actors: int,
) -> None:
    """Show the learner's progress from its status messages until it exits, and supervise the actors meanwhile.

    The bar runs on the learner's own training clock, carried forward between status messages (every 2 s) so it
    moves each second; past the duration the learner evaluates and writes its report and sends no more status.
    """
    from protocol import KeySpace, ZenohTransport

    keys = KeySpace(namespace)
    duration = learner.duration or 0.0
    latest: LearnerStatus | None = None
    received = 0.0
    lock = threading.Lock()

    def on_status(msg: Status) -> None:
        nonlocal latest, received
        with lock:
            latest = LearnerStatus.from_counters(msg.counters)
            received = time.monotonic()

    with ProgressBar("up", total=duration, unit="s") as bar, ZenohTransport.open(conf, keys) as transport:
        transport.subscribe(keys.status(learner.learner_id), Status, on_status)
        bar.show(status=f"starting the learner and {actors} actor(s)")
        version, coverage = 0, -1.0
        while proc.poll() is None:
            time.sleep(1.0)
            for message in supervisor.check():
                bar.mark(message)
            with lock:
                status, age = latest, time.monotonic() - received
            if status is None:
                continue
            n = min(status.elapsed + age, duration)
            if version == 0 and status.policy_version > 0:
                bar.mark(f"phase 1 done: policy v{status.policy_version} sent, phase 2 starts", n)
            if status.coverage >= 0 and status.coverage != coverage:
                bar.mark(f"evaluation: policy v{status.policy_version} observes {status.coverage:.1f}% of targets", n)
            version, coverage = status.policy_version, status.coverage
            bar.show(n, "training over: final evaluation and report" if n >= duration else cluster_status(status))
