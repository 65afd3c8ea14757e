"""Key expressions, payload encoding and QoS of the ENNC-QL wire protocol, in one place.

All keys live under ``[namespace/]enncql/v<SCHEMA_VERSION>/`` so that incompatible schema versions never
meet and independent runs can share one network::

    keys = KeySpace()                       # or KeySpace(namespace="run-42")
    keys.experience("actor-3")              # 'enncql/v2/experience/actor-3'  (actor -> learner)
    keys.experience()                       # 'enncql/v2/experience/*'        (learner subscribes)
    keys.qos(keys.experience("actor-3"))    # QoS(reliable=True, congestion_control=BLOCK, ...)

======================  ============================  ==============  =====================
key                     message                       direction       QoS
======================  ============================  ==============  =====================
experience/{actor_id}   ExperienceBatch               actor → learner reliable, BLOCK
qinc/{actor_id}         QTableIncrement               actor → learner reliable, BLOCK
ack/{actor_id}          Ack                           learner → actor reliable, BLOCK, express
policy                  PolicyUpdate (broadcast)      learner → all   reliable, BLOCK
policy/latest           PolicyUpdate (queryable)      learner → asker reply to a get
status/{sender}         Status                        any → any       best effort, DROP
view/{actor_id}         ActorView                     actor → learner best effort, DROP
alive/{role}/{id}       (liveliness token)            any             session lifetime
======================  ============================  ==============  =====================
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import zenoh

from protocol.messages import (
    ROLES,
    SCHEMA_VERSION,
    Ack,
    ActorView,
    ExperienceBatch,
    IdentityMismatch,
    InvalidValues,
    Message,
    PolicyUpdate,
    QTableIncrement,
    Reject,
    Status,
    UnexpectedMessageType,
    check_id,
)

ROOT = f"enncql/v{SCHEMA_VERSION}"
"""Key prefix of this schema version (below the optional namespace)."""

ENCODING = zenoh.Encoding("application/msgpack").with_schema(ROOT)
"""Zenoh encoding attached to every payload: msgpack envelope of schema ``ROOT``."""

WILD = "*"
"""Matches any one identifier chunk; pass it instead of an id to build a subscription key."""


class Channel(enum.Enum):
    """The kinds of traffic; each has one message type and one QoS."""

    EXPERIENCE = "experience"
    QINC = "qinc"
    ACK = "ack"
    REJECT = "reject"
    POLICY = "policy"
    STATUS = "status"
    VIEW = "view"
    ALIVE = "alive"


@dataclass(frozen=True, slots=True)
class QoS:
    """Publication settings of a channel (zenoh ``declare_publisher`` arguments)."""

    reliable: bool
    congestion_control: zenoh.CongestionControl
    priority: zenoh.Priority
    express: bool = False

    @property
    def reliability(self) -> zenoh.Reliability:
        """The zenoh reliability enum of ``reliable``."""
        return zenoh.Reliability.RELIABLE if self.reliable else zenoh.Reliability.BEST_EFFORT


_BLOCK, _DROP = zenoh.CongestionControl.BLOCK, zenoh.CongestionControl.DROP

# BLOCK everywhere data matters: zenoh's default DROP silently loses samples whenever the consumer lags.
QOS: Mapping[Channel, QoS] = MappingProxyType(
    {
        Channel.EXPERIENCE: QoS(True, _BLOCK, zenoh.Priority.DATA),
        Channel.QINC: QoS(True, _BLOCK, zenoh.Priority.DATA),
        # Express (no batching): acks are tiny and gate the actor's outbox, so latency matters more than batching.
        Channel.ACK: QoS(True, _BLOCK, zenoh.Priority.DATA_HIGH, express=True),
        Channel.REJECT: QoS(True, _BLOCK, zenoh.Priority.DATA_HIGH, express=True),
        Channel.POLICY: QoS(True, _BLOCK, zenoh.Priority.DATA_HIGH),
        Channel.STATUS: QoS(False, _DROP, zenoh.Priority.DATA_LOW),
        Channel.VIEW: QoS(False, _DROP, zenoh.Priority.DATA_LOW),
    }
)

MESSAGE_OF: Mapping[Channel, type[Message]] = MappingProxyType(
    {
        Channel.EXPERIENCE: ExperienceBatch,
        Channel.QINC: QTableIncrement,
        Channel.ACK: Ack,
        Channel.REJECT: Reject,
        Channel.POLICY: PolicyUpdate,
        Channel.STATUS: Status,
        Channel.VIEW: ActorView,
    }
)


# Number of id chunks after the channel name (the policy keys are handled on their own).
_ID_CHUNKS = {
    Channel.EXPERIENCE: 1,
    Channel.QINC: 1,
    Channel.ACK: 1,
    Channel.REJECT: 1,
    Channel.STATUS: 1,
    Channel.VIEW: 1,
    Channel.ALIVE: 2,
}
_BY_NAME = {c.value: c for c in _ID_CHUNKS}


def _id_or_wild(value: str, what: str) -> str:
    return value if value == WILD else check_id(value, what)


@dataclass(frozen=True, slots=True)
class KeySpace:
    """Builds and parses the protocol's keys under an optional ``namespace`` (ids joined by ``/``)."""

    namespace: str = ""

    def __post_init__(self) -> None:
        if self.namespace:
            for chunk in self.namespace.split("/"):
                check_id(chunk, "namespace chunk")

    @property
    def root(self) -> str:
        """``[namespace/]enncql/v2``."""
        return f"{self.namespace}/{ROOT}" if self.namespace else ROOT

    def experience(self, actor_id: str = WILD) -> str:
        """Where ``actor_id`` publishes its ExperienceBatches."""
        return f"{self.root}/experience/{_id_or_wild(actor_id, 'actor_id')}"

    def qinc(self, actor_id: str = WILD) -> str:
        """Where ``actor_id`` publishes its QTableIncrements."""
        return f"{self.root}/qinc/{_id_or_wild(actor_id, 'actor_id')}"

    def ack(self, actor_id: str = WILD) -> str:
        """Where the learner publishes the Acks for ``actor_id``."""
        return f"{self.root}/ack/{_id_or_wild(actor_id, 'actor_id')}"

    def reject(self, actor_id: str = WILD) -> str:
        """Where the learner publishes the Rejects of ``actor_id``'s messages it refused for good."""
        return f"{self.root}/reject/{_id_or_wild(actor_id, 'actor_id')}"

    def policy(self) -> str:
        """Where the learner broadcasts each new PolicyUpdate."""
        return f"{self.root}/policy"

    def policy_latest(self) -> str:
        """The learner's queryable answering the current PolicyUpdate (for late joiners)."""
        return f"{self.root}/policy/latest"

    def status(self, sender: str = WILD) -> str:
        """Where ``sender`` publishes its Status."""
        return f"{self.root}/status/{_id_or_wild(sender, 'sender')}"

    def view(self, actor_id: str = WILD) -> str:
        """Where ``actor_id`` publishes its ActorViews for the learner to log (``--rerun learner``)."""
        return f"{self.root}/view/{_id_or_wild(actor_id, 'actor_id')}"

    def alive(self, role: str = WILD, ident: str = WILD) -> str:
        """Liveliness token key of process ``ident`` in ``role`` (learner, actor or evaluator)."""
        if role != WILD and role not in ROLES:
            raise InvalidValues(f"role {role!r} not one of {ROLES}")
        return f"{self.root}/alive/{role}/{_id_or_wild(ident, 'id')}"

    def channel(self, key: str) -> Channel:
        """The channel of a key built by this KeySpace; :class:`InvalidValues` for any other key."""
        prefix = self.root + "/"
        if key.startswith(prefix):
            head, *rest = key[len(prefix) :].split("/")
            if head == Channel.POLICY.value and rest in ([], ["latest"]):
                return Channel.POLICY
            channel = _BY_NAME.get(head)
            if channel is not None and len(rest) == _ID_CHUNKS[channel]:
                return channel
        raise InvalidValues(f"{key!r} is not a key of this protocol under {self.root!r}")

    def _data_channel(self, key: str) -> Channel:
        channel = self.channel(key)
        if channel is Channel.ALIVE:
            raise InvalidValues(f"{key!r} is a liveliness key and carries no messages")
        return channel

    def owner(self, key: str) -> str | None:
        """The id a per-sender key names (``experience/<actor>``, ``qinc/<actor>``, ``ack/<actor>``,
        ``status/<sender>``, ``view/<actor>``); None for the policy keys."""
        channel = self._data_channel(key)
        return None if channel is Channel.POLICY else key.rsplit("/", 1)[-1]

    def check_message(self, key: str, msg: Message) -> None:
        """``msg`` may travel on ``key``: its type is the key's, and the sender it names is the key's own.

        Raises :class:`UnexpectedMessageType` or :class:`IdentityMismatch` (and :class:`InvalidValues` for a key
        that is not the protocol's).
        """
        if not isinstance(msg, self.message_type(key)):
            raise UnexpectedMessageType(f"a {msg.TAG} message cannot travel on {key!r}")
        owner = self.owner(key)
        claimed = getattr(msg, "actor_id", None) or getattr(msg, "sender", None)
        if owner is not None and claimed != owner:
            raise IdentityMismatch(f"a {msg.TAG} message of {claimed!r} on {owner!r}'s key {key!r}")

    def qos(self, key: str) -> QoS:
        """Publication QoS of ``key``."""
        return QOS[self._data_channel(key)]

    def message_type(self, key: str) -> type[Message]:
        """The only message type allowed on ``key``."""
        return MESSAGE_OF[self._data_channel(key)]


DEFAULT_KEYS = KeySpace()
"""The KeySpace without namespace."""
