"""``ennc-ql up``: the embedded default cluster on this machine.

One learner and N actor processes (real OS processes, the same commands a multi-machine run uses), joined by
Zenoh in peer mode on a loopback endpoint with multicast scouting off, so nothing leaves the machine and no router
is needed. Every actor learns every robot's table (option 2); the learner averages their changes by visits.
Progress (a bar on a terminal, plain lines otherwise, on stderr) comes from the learner's status messages; each
process logs to ``runs/<id>/<name>.log``. When the learner's duration is over it writes its report, the actors are
stopped, the results are printed and ``runs/<id>/report.md`` and ``learning_curve.png`` are written.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import IO, Any

from ennc_ql.progress import ProgressBar
from ennc_ql.report import results_table, write_run_report
from monitor import (
    Monitor,
    RecordingError,
    Sink,
    add_rerun_args,
    merge_recordings,
    open_monitor,
    paths,
    summarize_recording,
)
from monitor.recordings import rerun_cli
from protocol import Status, ZenohTransport, zenoh_config
from protocol.keys import KeySpace

log = logging.getLogger(__name__)

ACTOR_NICENESS = 10


def free_port() -> int:
    """A loopback TCP port that is free now, below Linux's ephemeral range so Zenoh's own sockets cannot take it."""
    for port in range(20000 + (int(time.time() * 1000) % 9000), 32000):
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError("no free TCP port in 20000-32000 on 127.0.0.1")


def add_up_parser(sub: Any) -> None:
    p = sub.add_parser("up", help="learner + N actors as local processes (embedded Zenoh, peer mode on loopback)")
    p.add_argument("--actors", type=int, default=2, help="actor processes (default 2)")
    p.add_argument("--duration", type=float, default=480.0, help="seconds of training (default 480)")
    p.add_argument("--arenas", type=int, default=500, help="arenas per actor (default 500)")
    p.add_argument("--min-tuples", type=int, default=150_000, help="tuples before the first phase 1")
    p.add_argument("--store-capacity", type=int, default=400_000, help="tuples the learner keeps (default 400000)")
    p.add_argument("--phase1-patterns", type=int, default=30_000, help="tuples per action in phase 1")
    p.add_argument("--eval-interval", type=float, default=30.0, help="seconds between evaluations")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--runs", default="runs", help="parent folder of the run folder (default runs/)")
    p.add_argument("--run-id", help="run folder name (default: a timestamp)")
    p.add_argument("--json", action="store_true", help="print the learner's report as one JSON object")
    add_rerun_args(p, default=None, default_text="save runs/<id>/recording.rrd")
    p.set_defaults(func=cmd_up)


VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"
"""Where a viewer spawned by ``up`` (or its ``rerun --serve-grpc`` proxy) takes the children's streams."""


class _Monitoring:
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
            print("ennc-ql up: watch with: rerun --connect rerun+http://<this host>:9876/proxy", file=sys.stderr)

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
            _stop(self.proxy, grace=5.0)
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


def _spawn(argv: list[str], log_file: IO[str], nice: int = 0) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "ennc_ql.cli", *argv],
        stdout=subprocess.DEVNULL,
        stderr=log_file,
        stdin=subprocess.DEVNULL,
        # preexec_fn is unsafe with threads; every child is spawned before the launcher opens its Zenoh session.
        preexec_fn=(lambda: os.nice(nice)) if nice else None,
    )


def _stop(proc: subprocess.Popen[bytes], grace: float) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _settings(args: argparse.Namespace) -> dict[str, int | float]:
    """The flags that shape a run, by name: they go into the report and rebuild its command line."""
    names = ("actors", "duration", "arenas", "min_tuples", "store_capacity", "phase1_patterns", "eval_interval", "seed")
    return {name: getattr(args, name) for name in names}


def _command(settings: dict[str, int | float]) -> str:
    flags = ["ennc-ql up"]
    for name, value in settings.items():
        # Whole-number floats print as ints (480.0 -> 480); ints keep every digit (1000000, not 1e+06).
        flags.append(f"--{name.replace('_', '-')} {f'{value:g}' if isinstance(value, float) else value}")
    return " ".join(flags)


def _learner_argv(args: argparse.Namespace, common: list[str], endpoint: str, run_dir: Path) -> list[str]:
    return [
        "learner",
        *common,
        "--listen",
        endpoint,
        "--run-dir",
        str(run_dir),
        "--duration",
        str(args.duration),
        "--min-tuples",
        str(args.min_tuples),
        "--store-capacity",
        str(args.store_capacity),
        "--phase1-patterns",
        str(args.phase1_patterns),
        "--eval-interval",
        str(args.eval_interval),
        "--seed",
        str(args.seed),
        "--threads",
        "1",
    ]


def cmd_up(args: argparse.Namespace) -> int:
    if args.actors < 1:
        raise SystemExit("ennc-ql up: --actors must be at least 1")
    run_id = args.run_id or time.strftime("%Y%m%d-%H%M%S")
    run_dir = Path(args.runs) / run_id
    run_dir.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    namespace = f"run-{run_id}".replace(":", "-")
    common = ["--namespace", namespace, "--no-multicast-scouting"]
    print(
        f"ennc-ql up: run {run_id}: learner + {args.actors} actors on {endpoint}, {args.duration:.0f} s",
        file=sys.stderr,
    )
    monitoring = _Monitoring(args.rerun or Sink("save", str(run_dir / paths.RECORDING_FILE)), run_id, run_dir)
    started = time.monotonic()
    with ExitStack() as stack:
        learner_log = stack.enter_context(open(run_dir / "learner.log", "w"))
        learner_argv = [*_learner_argv(args, common, endpoint, run_dir), *monitoring.child_args("learner")]
        learner = _spawn(learner_argv, learner_log)
        actors: list[subprocess.Popen[bytes]] = []
        try:
            for i in range(args.actors):
                actor_log = stack.enter_context(open(run_dir / f"actor-{i}.log", "w"))
                actor_argv = [
                    "actor",
                    *common,
                    "--connect",
                    endpoint,
                    "--id",
                    f"actor-{i}",
                    "--arenas",
                    str(args.arenas),
                    "--seed",
                    str(args.seed),
                    *monitoring.child_args(f"actor-{i}"),
                ]
                # Actors produce experience faster than one learner digests it on a shared machine: they yield
                # the CPU to the learner so phase 1 and evaluations are not starved.
                actors.append(_spawn(actor_argv, actor_log, nice=ACTOR_NICENESS))
            # After the children are spawned: their preexec_fn must not run while this process has threads.
            monitoring.start()
            _watch(endpoint, KeySpace(namespace), learner, args.actors, args.duration)
        finally:
            for proc in actors:
                _stop(proc, grace=10.0)
            _stop(learner, grace=60.0)
            recording = monitoring.finish()
    report_path = run_dir / "report.json"
    if not report_path.exists():
        raise SystemExit(f"ennc-ql up: the learner wrote no report; see {run_dir / 'learner.log'}")
    report: dict[str, Any] = json.loads(report_path.read_text())
    settings = _settings(args)
    report.update(
        run_id=run_id,
        run_dir=str(run_dir),
        command=_command(settings),
        config={**settings, "endpoint": endpoint},
        wall_seconds=round(time.monotonic() - started, 1),
        recording=recording,
    )
    if report.get("policy_file"):
        # Imported here: bench_transport's publisher processes import this module and need no simulator.
        from algorithm.policy_file import load_policy, scenario_from_header
        from ennc_ql.figures import policy_figure

        policy, header = load_policy(report["policy_file"])
        report["policy_figure"] = str(policy_figure(policy, scenario_from_header(header), run_dir / "policy.png"))
    markdown, png = write_run_report(report, run_dir)
    report.update(report_md=str(markdown), learning_curve=str(png))
    report_path.write_text(json.dumps(report, indent=2))
    if args.json:
        print(json.dumps(report))
    else:
        print(results_table(report))
        print(f"report: {markdown} (learning curve {png})")
    return 0


def cluster_status(counters: dict[str, float]) -> str:
    """The live figures of the learner's status counters, as the progress bar shows them."""
    version = int(counters.get("policy_version", 0))
    coverage = counters.get("coverage", -1.0)
    return (
        f"{'exploring' if version == 0 else 'phase 2'}: {int(counters.get('tuples_received', 0)):,} tuples "
        f"({counters.get('tuples_per_s', 0.0) / 1e3:.0f} k/s), policy v{version}, "
        f"{int(counters.get('live_actors', 0))} actors, coverage {'–' if coverage < 0 else f'{coverage:.1f}%'}"
    )


def _watch(endpoint: str, keys: KeySpace, learner: subprocess.Popen[bytes], actors: int, duration: float) -> None:
    """Show the learner's progress from its status messages until it exits.

    The bar runs on the learner's own training clock, carried forward between status messages (every 2 s) so it
    moves each second; past the duration the learner evaluates and writes its report and sends no more status.
    """
    latest: dict[str, float] = {}
    received = 0.0
    lock = threading.Lock()

    def on_status(status: Status) -> None:
        nonlocal received
        with lock:
            latest.update(status.counters)
            received = time.monotonic()

    conf = zenoh_config(connect=[endpoint], mode="peer", multicast_scouting=False)
    with ProgressBar("up", total=duration, unit="s") as bar, ZenohTransport.open(conf, keys) as transport:
        transport.subscribe(keys.status("learner"), Status, on_status)
        bar.show(status=f"starting the learner and {actors} actor(s)")
        version, coverage = 0, -1.0
        while learner.poll() is None:
            time.sleep(1.0)
            with lock:
                c, age = dict(latest), time.monotonic() - received
            if not c:
                continue
            n = min(c.get("elapsed", 0.0) + age, duration)
            if version == 0 and c.get("policy_version", 0) > 0:
                bar.mark(f"phase 1 done: policy v{int(c['policy_version'])} sent, phase 2 starts", n)
            if c.get("coverage", -1.0) >= 0 and c["coverage"] != coverage:
                bar.mark(f"evaluation: policy v{int(c['policy_version'])} observes {c['coverage']:.1f}% of targets", n)
            version, coverage = int(c.get("policy_version", 0)), c.get("coverage", -1.0)
            finishing = n >= duration
            bar.show(n, "training over: final evaluation and report" if finishing else cluster_status(c))
