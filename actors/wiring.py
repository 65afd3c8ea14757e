"""Every subscription of the actor process, in one place (Sample Factory's ``connect_components``).

Usage::

    handles = connect(actor, transport)
    ...
    for handle in reversed(handles):
        handle.close()
"""

from __future__ import annotations

from actors.actor import RobotActor
from protocol import Ack, Closeable, PolicyUpdate, Reject, Transport


def _ignore(_key: str) -> None:
    return None


def connect(actor: RobotActor, transport: Transport) -> list[Closeable]:
    keys, me = transport.keys, actor.config.actor_id
    handles = [
        # Our token: the learner counts us live while it exists (gone at once if killed, after the lease if hung).
        transport.liveliness_token(keys.alive("actor", me)),
        # Policy broadcasts: the newest is adopted between trials.
        transport.subscribe(keys.policy(), PolicyUpdate, actor.policy.offer),
        # Cumulative acks of our stream: acknowledged messages leave the outbox.
        transport.subscribe(keys.ack(me), Ack, actor.outbox.on_ack),
        # Messages of ours the learner refused for good: dropped from the outbox instead of re-sent forever.
        transport.subscribe(keys.reject(me), Reject, actor.outbox.on_reject),
        # A learner (re)joining has not seen our unacknowledged messages: the outbox re-sends them.
        transport.liveliness_subscribe(keys.alive("learner"), actor.outbox.on_learner_join, _ignore),
    ]
    # A late joiner asks for the current policy instead of waiting for the next broadcast.
    for update in transport.get(keys.policy_latest(), PolicyUpdate):
        actor.policy.offer(update)
    return handles
