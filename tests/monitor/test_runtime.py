"""The learner service and two actors in one process: each actor with its own monitor on the run's recording id, or
relaying its rows to the learner (``--rerun learner``, what ``ennc-ql up`` does).

What the runtime logs (not what the monitor API can log): the merged recording holds the learner's status series,
its evaluations and prototypes, and each actor's sampled arena and trial figures, whichever process wrote them.
"""

from __future__ import annotations

import threading
from functools import partial
from pathlib import Path

import pytest

from actors.actor import RobotActor
from actors.config import ActorConfig
from actors.wiring import connect as connect_actor
from algorithm.phase1 import Phase1Config
from learner.config import LearnerConfig
from learner.service import LearnerService
from learner.wiring import connect as connect_learner
from monitor import Sink, merge_recordings, open_monitor, paths, summarize_recording
from monitor.relay import RelayMonitor
from protocol import InMemoryBus, InMemoryTransport
from sim import HAND_MADE, N_ACTIONS
from tests.fakes import run_until
from tests.monitor.rrd import rows

CONFIG = LearnerConfig(
    min_tuples=6000,
    phase1=Phase1Config(max_iterations=1, n_cycles=10, max_patterns=500),
    broadcast_interval=0.5,
    eval_interval=1000.0,  # the final evaluation is the one logged
    eval_trials=1,
    eval_steps=50,
    checkpoint_interval=0.5,
    status_interval=0.2,
    duration=120.0,
)


@pytest.mark.slow
@pytest.mark.parametrize("relay", [False, True], ids=["own-recordings", "relayed-by-the-learner"])
def test_learner_and_actors_log_into_one_recording(tmp_path: Path, relay: bool) -> None:
    run_id = "runtime-test"
    bus = InMemoryBus()
    actor_ids = ["a0", "a1"]
    with (
        open_monitor(
            Sink("save", str(paths.part_file(tmp_path, "learner"))), process="learner", recording_id=run_id
        ) as learner_monitor,
        InMemoryTransport(bus) as lt,
    ):
        service = LearnerService(lt, CONFIG, tmp_path, monitor=learner_monitor)
        handles = connect_learner(service, lt)
        actors, threads, monitors, transports = [], [], [], []
        stop = threading.Event()
        for i, actor_id in enumerate(actor_ids):
            transport = InMemoryTransport(bus)
            monitor = (
                RelayMonitor(partial(transport.publish, transport.keys.view(actor_id)), actor_id)
                if relay
                else open_monitor(
                    Sink("save", str(paths.part_file(tmp_path, actor_id))), process=actor_id, recording_id=run_id
                )
            )
            config = ActorConfig(actor_id=actor_id, arenas=8, seed=i, batch_size=512, flush_timeout=0.5, draw_every=2)
            actor = RobotActor(transport, config, monitor=monitor)
            handles.enter_context(connect_actor(actor, transport))
            actors.append(actor)
            monitors.append(monitor)
            transports.append(transport)
            threads.append(threading.Thread(target=actor.run, args=(stop,)))
        for thread in threads:
            thread.start()
        # A policy was broadcast and both actors ran a few trials.
        report = run_until(service, lambda: service.state.version >= 2 and all(a.status().trials >= 4 for a in actors))
        stop.set()
        for thread in threads:
            thread.join()
        handles.close()  # the ExitStack connect returned: every handle, in reverse order
        for monitor, transport in zip(monitors, transports, strict=True):
            monitor.close()
            transport.close()
        trials = {a.config.actor_id: a.status().trials for a in actors}

    parts = sorted((tmp_path / "rerun").glob("*.rrd"))
    assert len(parts) == (1 if relay else 3)  # relaying actors open no recording
    if relay:
        assert [m.sent for m in monitors] == [trials[a] for a in actor_ids]  # one view per trial, none dropped
    recording = merge_recordings(parts, tmp_path / paths.RECORDING_FILE)
    summary = summarize_recording(recording)
    assert summary["recording_ids"] == [run_id]
    entities = set(summary["entity_paths"])
    for actor_id in actor_ids:
        arena = paths.actor_arena(actor_id)
        assert {f"{arena}/robots", f"{arena}/targets", f"{arena}/sensing"} <= entities
        # One coverage point per trial, and every step of every drawn trial (trials 0, 2, 4, ...) has an arena.
        coverage = rows(recording, paths.actor(actor_id, paths.ACTOR_COVERAGE), "Scalars:scalars", paths.SIM_STEP)
        assert len(coverage) == trials[actor_id]
        assert all(0.0 <= value[0] <= 100.0 for _, value in coverage)
        drawn = rows(recording, f"{paths.actor_arena(actor_id)}/robots", "Points2D:positions", paths.SIM_STEP)
        assert len(drawn) == len(range(0, trials[actor_id], 2)) * 100  # learning trials are 100 steps
        # The actor's own timelines: the drawn steps of trial k are k·100 + 1 … k·100 + 100.
        assert [step for step, _ in drawn[:100]] == list(range(1, 101))
        memory = rows(recording, paths.actor(actor_id, paths.ACTOR_RSS), "Scalars:scalars", paths.SIM_STEP)
        assert len(memory) == trials[actor_id] and all(value[0] > 50.0 for _, value in memory)
    # The final figure is a marker of its own beside the curve, with the hand-made levels on the curve's trials.
    ((_, final),) = rows(recording, paths.LEARNER_COVERAGE_FINAL, "Scalars:scalars", paths.POLICY_VERSION)
    assert final[0] == pytest.approx(report.final_coverage_mean, abs=1e-3)
    assert {paths.reference(name) for name in HAND_MADE} <= entities
    assert {paths.prototypes_of(k) for k in range(N_ACTIONS)} <= entities
    assert {paths.learner_lag(a) for a in actor_ids} <= entities
    assert rows(recording, paths.LEARNER_STORE_SIZE, "Scalars:scalars", paths.LEARNER_STEP)
