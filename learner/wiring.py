"""Every subscription of the learner process, in one place (Sample Factory's ``connect_components``).

Usage::

    handles = connect(service, transport)
    ...
    for handle in reversed(handles):
        handle.close()
"""

from __future__ import annotations

from learner.service import LearnerService
from protocol import Closeable, ExperienceBatch, QTableIncrement, Transport


def connect(service: LearnerService, transport: Transport) -> list[Closeable]:
    keys, me, intake = transport.keys, service.config.learner_id, service.intake
    handles = [
        # Experience of every actor into the de-duplicating store; a refused one is rejected by its seq.
        transport.subscribe(keys.experience(), ExperienceBatch, intake.on_experience, intake.on_rejected),
        # Q-table increments of every actor, queued for the next merge; a refused one is rejected by its seq.
        transport.subscribe(keys.qinc(), QTableIncrement, service.on_increment, intake.on_rejected),
        # A late-joining actor asks for the current policy instead of waiting for the next broadcast.
        transport.declare_queryable(keys.policy_latest(), lambda: service.state.current),
        # Membership: actors' liveliness tokens appear and vanish (killed at once, hung after the lease).
        transport.liveliness_subscribe(keys.alive("actor"), service.members.on_join, service.members.on_leave),
        # Our own token: actors re-send their unacknowledged outbox when a (re)started learner appears.
        transport.liveliness_token(keys.alive("learner", me)),
    ]
    service.announce()
    return handles
