"""Every subscription of the actor process, in one place (Sample Factory's ``connect_components``).

Usage::

    with connect(actor, transport):   # one ExitStack: every handle closes, in reverse order, on leaving it
        status = actor.run(stop)
"""

from __future__ import annotations

from contextlib import ExitStack

from actors.actor import RobotActor
from protocol import Ack, PolicyUpdate, Reject, Transport


def _ignore(_key: str) -> None:
    return None


def connect(actor: RobotActor, transport: Transport) -> ExitStack:
    keys, me = transport.keys, actor.config.actor_id
    with ExitStack() as stack:  # a failure part-way closes what was opened before it
        # Our token: the learner counts us live while it exists (gone at once if killed, after the lease if hung).
        stack.callback(transport.liveliness_token(keys.alive("actor", me)).close)
        # Policy broadcasts: the newest is adopted between trials.
        stack.callback(transport.subscribe(keys.policy(), PolicyUpdate, actor.policy.offer).close)
        # Cumulative acks of our stream: acknowledged messages leave the outbox.
        stack.callback(transport.subscribe(keys.ack(me), Ack, actor.outbox.on_ack).close)
        # Messages of ours the learner refused for good: dropped from the outbox instead of re-sent forever.
        stack.callback(transport.subscribe(keys.reject(me), Reject, actor.outbox.on_reject).close)
        # A learner (re)joining has not seen our unacknowledged messages: the outbox re-sends them.
        learner = keys.alive("learner")
        stack.callback(transport.liveliness_subscribe(learner, actor.outbox.on_learner_join, _ignore).close)
        # A late joiner asks for the current policy instead of waiting for the next broadcast.
        for update in transport.get(keys.policy_latest(), PolicyUpdate):
            actor.policy.offer(update)
        return stack.pop_all()
