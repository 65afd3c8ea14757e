"""The serial topology: the learner and the actors as objects in this process on one in-memory bus (Sample Factory's
``serial_mode``), for a debugger or a profiler; the same objects and the same report as the process topology::

    report = run_serial(learner, actors, run_dir)
"""

from __future__ import annotations

import logging
import threading
from contextlib import ExitStack
from pathlib import Path

from actors.actor import RobotActor
from actors.config import ActorConfig
from actors.wiring import connect as connect_actor
from learner.config import LearnerConfig
from learner.report import LearnerReport
from learner.service import LearnerService
from learner.wiring import connect as connect_learner
from protocol import InMemoryBus, InMemoryTransport

log = logging.getLogger(__name__)


def run_serial(
    learner: LearnerConfig, actors: list[ActorConfig], run_dir: Path, stop: threading.Event | None = None
) -> LearnerReport:
    """Every process as an object on its own thread; ends when the learner's duration is over, as the process
    topology does, or once ``stop`` is set (the learner then scores its policy and reports, as on SIGTERM)."""
    bus = InMemoryBus()
    stop_actors = threading.Event()
    with ExitStack() as stack:
        learner_transport = stack.enter_context(InMemoryTransport(bus))
        service = LearnerService(learner_transport, learner, run_dir)
        stack.enter_context(connect_learner(service, learner_transport))
        threads = []
        for config in actors:
            transport = stack.enter_context(InMemoryTransport(bus))
            actor = RobotActor(transport, config)
            stack.enter_context(connect_actor(actor, transport))
            threads.append(threading.Thread(target=actor.run, args=(stop_actors,), name=config.actor_id))
        for thread in threads:
            thread.start()
        try:
            log.info(
                "serial: the learner and %d actor(s) in this process for %.0f s", len(actors), learner.duration or 0
            )
            report = service.run(stop or threading.Event())
        finally:
            stop_actors.set()
            for thread in threads:
                thread.join()
    return report
