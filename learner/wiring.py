"""Every subscription of the learner process, in one place (Sample Factory's ``connect_components``).

Usage::

    with connect(service, transport):   # one ExitStack: every handle closes, in reverse order, on leaving it
        report = service.run(stop)
"""

from __future__ import annotations

from contextlib import ExitStack

from learner.service import LearnerService
from protocol import ActorView, ExperienceBatch, QTableIncrement, Transport


def connect(service: LearnerService, transport: Transport) -> ExitStack:
    keys, me, intake = transport.keys, service.config.learner_id, service.intake
    with ExitStack() as stack:  # a failure part-way closes what was opened before it
        # Experience of every actor into the de-duplicating store; a refused one is rejected by its seq.
        stack.callback(
            transport.subscribe(keys.experience(), ExperienceBatch, intake.on_experience, intake.on_rejected).close
        )
        # Q-table increments of every actor, queued for the next merge; a refused one is rejected by its seq.
        stack.callback(
            transport.subscribe(keys.qinc(), QTableIncrement, service.on_increment, intake.on_rejected).close
        )
        # The viewer rows of actors that relay them (``--rerun learner``), into this process's recording.
        if service.watch.monitor.enabled:
            stack.callback(transport.subscribe(keys.view(), ActorView, service.watch.monitor.actor_view).close)
        # A late-joining actor asks for the current policy instead of waiting for the next broadcast.
        stack.callback(transport.declare_queryable(keys.policy_latest(), lambda: service.state.current).close)
        # Membership: actors' liveliness tokens appear and vanish (killed at once, hung after the lease).
        members = service.members
        stack.callback(transport.liveliness_subscribe(keys.alive("actor"), members.on_join, members.on_leave).close)
        # Our own token: actors re-send their unacknowledged outbox when a (re)started learner appears.
        stack.callback(transport.liveliness_token(keys.alive("learner", me)).close)
        service.announce()
        return stack.pop_all()
