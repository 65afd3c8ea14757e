"""One recording from several processes: part files with a shared recording id, merged and read back."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from monitor import RecordingError, Sink, merge_recordings, open_monitor, paths, style, summarize_recording
from monitor.geometry import observed_targets
from monitor.recordings import rerun_cli
from sim.formulation import default_formulation
from tests.monitor.rrd import layout, rows
from tools.system import free_port

REPO = Path(__file__).resolve().parents[2]
RECORDING_ID = "test-run-1"
N_ACTIONS = 3
VERSIONS = (1, 2, 3)
ACTOR_STEPS = (0, 10, 20, 30, 40)


def arena_at(step: int) -> tuple[np.ndarray, np.ndarray]:
    """Robot and target positions of the actor's sampled arena at ``step`` (close together, so some observed)."""
    rng = np.random.default_rng(step)
    return rng.uniform(-300.0, 300.0, (10, 2)), rng.uniform(-300.0, 300.0, (10, 2))


def prototypes_at(version: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    rng = np.random.default_rng(100 + version)
    sizes = (4, 0, 7)  # an action may have no prototype
    return [rng.normal(size=(p, 6)) for p in sizes], [rng.normal(size=p) for p in sizes]


# The actor is killed with SIGKILL after its last flush, as a launcher may kill a child: its part file has no footer.
ACTOR_SCRIPT = """
import os, signal, sys
from monitor import Sink, open_monitor, paths
from tests.monitor.test_recordings import ACTOR_STEPS, arena_at
monitor = open_monitor(Sink("save", sys.argv[1]), process="actor-0", recording_id=sys.argv[2])
for t in ACTOR_STEPS:
    robots, targets = arena_at(t)
    monitor.arena(paths.actor_arena("actor-0"), robots, targets, sensing_range=150.0, arena_radius=1000.0, sim_step=t)
    monitor.actor_metrics("actor-0", sim_step=t, coverage=float(t), mean_reward=-0.5, tuples_per_s=1e4,
                          policy_version=1)
monitor.rec.flush()
os.kill(os.getpid(), signal.SIGKILL)
"""


def write_learner_part(path: Path) -> None:
    with open_monitor(Sink("save", str(path)), process="learner", recording_id=RECORDING_ID) as monitor:
        monitor.send_blueprint(["actor-0"], arena_radius=1000.0, sensing_range=150.0)
        for step, version in enumerate(VERSIONS):
            monitor.learner_metrics(
                learner_step=step,
                policy_version=version,
                tuples_per_s=1e5,
                live_actors=1,
                store_size=1000 * version,
                rejected=0,
                lag={"actor-0": version - 1},
            )
            monitor.eval_coverage(50.0 + version, policy_version=version, learner_step=step)
            protos, q = prototypes_at(version)
            monitor.q_stats(q, policy_version=version, learner_step=step)
            monitor.prototypes(protos, q, policy_version=version)


@pytest.fixture(scope="module")
def merged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("run")
    learner_part, actor_part = paths.part_file(run_dir, "learner"), paths.part_file(run_dir, "actor-0")
    actor = subprocess.Popen(
        [sys.executable, "-c", ACTOR_SCRIPT, str(actor_part), RECORDING_ID], cwd=REPO, stderr=subprocess.PIPE
    )
    write_learner_part(learner_part)
    _, stderr = actor.communicate(timeout=60)
    assert actor.returncode == -9, stderr.decode()
    return merge_recordings([learner_part, actor_part], run_dir / paths.RECORDING_FILE)


def test_merged_parts_form_one_recording(merged: Path) -> None:
    summary = summarize_recording(merged)
    assert summary["recording_ids"] == [RECORDING_ID]
    assert summary["application_ids"] == [paths.APPLICATION_ID]
    assert summary["blueprints"] == 1
    assert summary["size_bytes"] == merged.stat().st_size > 0
    timelines = {paths.SIM_STEP, paths.POLICY_VERSION, paths.LEARNER_STEP, paths.TRAIN_TIME, paths.WALL_TIME}
    assert timelines <= set(summary["timelines"])
    expected_rows = {
        paths.LEARNER_COVERAGE_EVAL: len(VERSIONS),
        paths.LEARNER_TUPLES_PER_S: len(VERSIONS),
        paths.LEARNER_POLICY_VERSION: len(VERSIONS),
        paths.LEARNER_LIVE_ACTORS: len(VERSIONS),
        paths.LEARNER_STORE_SIZE: len(VERSIONS),
        paths.LEARNER_REJECTED: len(VERSIONS),
        paths.learner_lag("actor-0"): len(VERSIONS),
        **{f"{paths.LEARNER_Q}/{stat}": len(VERSIONS) for stat in paths.Q_STATS},
        **{paths.prototypes_of(k): len(VERSIONS) for k in range(N_ACTIONS)},
        **{paths.actor("actor-0", m): len(ACTOR_STEPS) for m in ("coverage", "reward", "tuples_per_s")},
        **{f"{paths.actor_arena('actor-0')}/{part}": len(ACTOR_STEPS) for part in ("sensing", "robots", "targets")},
    }
    assert {entity: summary["rows_per_entity"].get(entity) for entity in expected_rows} == expected_rows
    assert f"{paths.actor_arena('actor-0')}/boundary" in summary["entity_paths"]  # static, so no timed rows


def test_scalars_keep_their_values_and_timelines(merged: Path) -> None:
    coverage = rows(merged, paths.LEARNER_COVERAGE_EVAL, "Scalars:scalars", paths.POLICY_VERSION)
    assert coverage == [(v, [50.0 + v]) for v in VERSIONS]
    lag = rows(merged, paths.learner_lag("actor-0"), "Scalars:scalars", paths.LEARNER_STEP)
    assert lag == [(i, [float(v - 1)]) for i, v in enumerate(VERSIONS)]
    actor_coverage = rows(merged, paths.actor("actor-0", "coverage"), "Scalars:scalars", paths.SIM_STEP)
    assert actor_coverage == [(t, [float(t)]) for t in ACTOR_STEPS]


def packed(color: style.Rgb) -> int:
    """RGBA packed into one integer, as Rerun stores colours."""
    return int.from_bytes(bytes(style.rgba(color)), "big")


def test_targets_are_coloured_by_observation(merged: Path) -> None:
    green, red = packed(style.OBSERVED), packed(style.UNOBSERVED)
    logged = rows(merged, f"{paths.actor_arena('actor-0')}/targets", "Points2D:colors", paths.SIM_STEP)
    assert [t for t, _ in logged] == list(ACTOR_STEPS)
    for t, colors in logged:
        robots, targets = arena_at(t)
        expected = np.where(observed_targets(robots, targets, 150.0), green, red)
        assert colors == expected.tolist()
    assert any(green in colors for _, colors in logged) and any(red in colors for _, colors in logged)


def test_prototypes_are_projected_with_their_q(merged: Path) -> None:
    positions = rows(merged, paths.prototypes_of(2), "Points2D:positions", paths.POLICY_VERSION)
    q_logged = rows(merged, paths.prototypes_of(2), "q", paths.POLICY_VERSION)
    for (version, points), (_, q) in zip(positions, q_logged, strict=True):
        protos, q_values = prototypes_at(version)
        np.testing.assert_allclose(points, protos[2][:, :2], rtol=1e-6)
        np.testing.assert_allclose(q, q_values[2])


def test_drawings_are_mirrored_north_up(merged: Path) -> None:
    """Rerun's 2-D views draw +y down: each drawing root mirrors y, so that north (+y) is drawn at the top."""
    flip = [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]
    for root in (paths.actor_arena("actor-0"), *(paths.prototypes_of(k) for k in range(N_ACTIONS))):
        (transform,) = [
            chunk.to_record_batch().column("Transform3D:mat3x3").to_pylist()[0]
            for chunk in RrdReader(merged).stream()
            if chunk.entity_path == f"/{root}" and chunk.is_static
        ]
        assert transform == [flip]


def test_training_blueprint_lays_out_every_actor_and_action(merged: Path) -> None:
    views = {view.name: (view.kind, view.origin) for view in layout(merged).views}
    spatial = {name: origin for name, (kind, origin) in views.items() if kind == "2D"}
    # The prototype views are the rose of the 8 moves, whatever the recording holds: the run's default formulation's
    # until a learner names its own.
    assert spatial == {
        "actor-0 arena": "actors/actor-0",
        "key": paths.KEY,
        **{name: paths.LEARNER_PROTOTYPES for name in default_formulation().actions.moves},
    }
    curves = {name for name, (kind, _) in views.items() if kind == "TimeSeries"}
    assert {"test coverage (%)", "training coverage (%)", "tuples/s", "policy version", "tuples stored"} <= curves


def test_each_call_carries_only_its_own_timelines(tmp_path: Path) -> None:
    path = tmp_path / "one.rrd"
    with open_monitor(Sink("save", str(path)), process="p", recording_id="r") as monitor:
        monitor.eval_coverage(10.0, policy_version=4, learner_step=2)
        monitor.scalars("a", {"b": 1.0}, sim_step=7)
    timelines = {
        chunk.entity_path: set(chunk.timeline_names) for chunk in RrdReader(path).stream() if not chunk.is_static
    }
    assert timelines[f"/{paths.LEARNER_COVERAGE_EVAL}"] - {"log_time"} == {
        "policy_version",
        "learner_step",
        "train_time",
        "wall_time",
    }
    assert timelines["/a/b"] - {"log_time"} == {"sim_step", "train_time", "wall_time"}


def test_train_time_comes_from_the_clock_in_use(tmp_path: Path) -> None:
    path = tmp_path / "clock.rrd"
    with open_monitor(Sink("save", str(path)), process="p", recording_id="r") as monitor:
        monitor.scalars("opened", {"x": 1.0})  # until a clock is given: seconds since the monitor opened
        monitor.use_clock(lambda: 12.5)
        monitor.scalars("run", {"x": 1.0})
    ((opened, _),) = rows(path, "opened/x", "Scalars:scalars", paths.TRAIN_TIME)
    assert 0 <= opened < 10e9  # nanoseconds
    assert rows(path, "run/x", "Scalars:scalars", paths.TRAIN_TIME) == [(12_500_000_000, [1.0])]


def test_merge_reports_bad_input(tmp_path: Path, merged: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"missing\.rrd"):
        merge_recordings([tmp_path / "missing.rrd"], tmp_path / "out.rrd")
    with pytest.raises(ValueError, match="also one of the parts"):
        merge_recordings([merged], merged)
    junk = tmp_path / "junk.rrd"
    junk.write_bytes(np.random.default_rng(0).bytes(1000))
    with pytest.raises(RecordingError, match="rrd merge"):
        merge_recordings([junk], tmp_path / "out.rrd")


def recorded(path: Path) -> set[str]:
    """The entity paths in the recording the server is writing now (none while a frame is half written)."""
    try:
        return set(summarize_recording(path)["entity_paths"])
    except (RuntimeError, RecordingError):
        return set()


def stop_server(server: subprocess.Popen[bytes], grace: float = 30.0) -> None:
    """SIGINT (the server writes what it holds and exits), then SIGKILL to its whole session past ``grace``: on
    loaded cores it may be slow to exit, and nothing of it may outlive the test."""
    server.send_signal(signal.SIGINT)
    try:
        server.wait(grace)
    except subprocess.TimeoutExpired:
        os.killpg(server.pid, signal.SIGKILL)
        server.wait()
    with contextlib.suppress(ProcessLookupError):  # anything it started, in its session
        os.killpg(server.pid, signal.SIGKILL)


def test_connect_streams_processes_into_one_live_recording(tmp_path: Path) -> None:
    """Two monitors connect to a listening ``rerun --save`` (a viewer would do the same) with one recording id."""
    out, port, log = tmp_path / "live.rrd", free_port(), tmp_path / "server.log"
    with open(log, "wb") as err:  # a file, not a pipe: a server that logs a lot never blocks on a full pipe
        server = subprocess.Popen(
            [*rerun_cli(), "--save", str(out), "--port", str(port)],
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,
        )
    try:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        for process in ("learner", "actor-0"):
            with open_monitor(Sink("connect", url), process=process, recording_id=RECORDING_ID) as monitor:
                monitor.scalars(process, {"ticks": 1.0}, learner_step=1)
        wanted = {"learner/ticks", "actor-0/ticks"}
        deadline = time.monotonic() + 30.0
        # close() returns once the data is sent; the server writes it to disk on its own schedule.
        while not (out.is_file() and wanted <= recorded(out)):
            assert time.monotonic() < deadline, "the live recording never received both processes' data"
            time.sleep(0.1)
    finally:
        stop_server(server)
    stderr = log.read_text(errors="replace")[-3000:]
    summary = summarize_recording(out)
    assert summary["recording_ids"] == [RECORDING_ID]
    assert summary["rows_per_entity"]["learner/ticks"] == summary["rows_per_entity"]["actor-0/ticks"] == 1, stderr
