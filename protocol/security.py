"""Zenoh security settings of the protocol: TLS with mutual authentication, user/password credentials, and the
access-control rules that bind each stream to its authenticated sender.

Every process connects to one router; the router is where the rules are enforced (zenoh checks ``ingress`` when a
message arrives from a peer and ``egress`` when it is forwarded to one). Identities are zenoh usernames, and each
subject also requires the certificate's common name to be the same id, so a stolen password without its key (or a
key without its password) gets nothing::

    rules = access_control(KeySpace("run-7"), learner_id="learner", actor_ids=["actor-0", "actor-1"])
    router = router_config(["tls/0.0.0.0:7447"], tls, credentials_file, rules, max_message_size)
    actor = client_config(["tls/localhost:7447"], tls_of_actor, "actor-0", password, max_message_size)

What each identity may do (deny by default; ``{root}`` is the KeySpace's root):

==================  =====================================================  ==========================================
identity            may publish (put, ingress)                             may receive (put, egress)
==================  =====================================================  ==========================================
learner             policy, ack/*, reject/*, status/{learner}              experience/*, qinc/*
actor-i             experience/actor-i, qinc/actor-i, status/actor-i       policy, ack/actor-i, reject/actor-i
observer            nothing                                                policy, status/*
==================  =====================================================  ==========================================

Only the learner declares the ``policy/latest`` queryable and replies to it; actors and observers may query it.
Liveliness tokens are each identity's own (``alive/learner/{learner}``, ``alive/actor/actor-i``); everyone sees
every token. Declaring subscribers is allowed everywhere under the root: what a subscriber receives is decided by
the ``put``/``reply`` egress rules above.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from protocol.codec import MAX_PAYLOAD_BYTES

if TYPE_CHECKING:  # only its methods are used: importing this module needs no zenoh
    from protocol.keys import KeySpace

OBSERVER = "observer"
"""The identity of read-only tools (``ennc-ql up``'s progress watch, ``chaos``' checks): status and policies."""

ROUTER = "router"
"""The router's own identity (its certificate's common name and its user name towards its peers)."""

MAX_MESSAGE_BYTES = MAX_PAYLOAD_BYTES + 64 * 1024
"""Zenoh's ``transport/link/rx/max_message_size``: the protocol's payload limit plus room for zenoh's own headers.

A larger message is dropped by zenoh while it is still being reassembled, so one link never buffers more than this
for one message (the protocol's own check after decoding would otherwise come after the whole message sat in
memory)."""


@dataclass(frozen=True, slots=True)
class TlsFiles:
    """The PEM files one process's TLS needs: the CA it trusts and its own certificate and key."""

    ca: str
    certificate: str
    key: str


def _rule(rule_id: str, messages: Sequence[str], flow: str, key_exprs: Sequence[str]) -> dict[str, Any]:
    return {
        "id": rule_id,
        "messages": list(messages),
        "flows": [flow],
        "permission": "allow",
        "key_exprs": list(key_exprs),
    }


def access_control(keys: KeySpace, learner_id: str, actor_ids: Sequence[str]) -> dict[str, Any]:
    """The router's ``access_control`` section for one learner, these actors and the observer identity."""
    everyone = [learner_id, *actor_ids, OBSERVER]
    rules = [
        _rule(
            "see-declarations", ["declare_subscriber", "declare_liveliness_subscriber"], "ingress", [keys.root + "/**"]
        ),
        _rule(
            "forward-declarations",
            ["declare_subscriber", "declare_liveliness_subscriber"],
            "egress",
            [keys.root + "/**"],
        ),
        _rule("see-tokens", ["liveliness_token", "liveliness_query"], "egress", [f"{keys.root}/alive/**"]),
        _rule("ask-tokens", ["liveliness_query"], "ingress", [f"{keys.root}/alive/**"]),
        _rule("ask-policy", ["query"], "ingress", [keys.policy_latest()]),
        _rule("hear-policy-queryable", ["declare_queryable", "reply"], "egress", [keys.policy_latest()]),
        _rule("hear-policy", ["put"], "egress", [keys.policy()]),
        # The learner's own powers.
        _rule(
            "learner-publish", ["put"], "ingress", [keys.policy(), keys.ack(), keys.reject(), keys.status(learner_id)]
        ),
        _rule("learner-serve", ["declare_queryable", "reply"], "ingress", [keys.policy_latest()]),
        _rule("learner-asked", ["query"], "egress", [keys.policy_latest()]),
        _rule("learner-receive", ["put"], "egress", [keys.experience(), keys.qinc(), keys.view()]),
        _rule("learner-token", ["liveliness_token"], "ingress", [keys.alive("learner", learner_id)]),
        _rule("observer-receive", ["put"], "egress", [keys.status()]),
    ]
    subjects = [{"id": ident, "usernames": [ident], "cert_common_names": [ident]} for ident in everyone]
    policies = [
        {"id": "everyone", "rules": [r["id"] for r in rules[:7]], "subjects": everyone},
        {"id": "learner", "rules": [r["id"] for r in rules[7:12]], "subjects": [learner_id]},
        {"id": "observer", "rules": ["observer-receive"], "subjects": [OBSERVER]},
    ]
    for actor in actor_ids:
        own = [f"{actor}-publish", f"{actor}-receive", f"{actor}-token"]
        rules += [
            _rule(
                own[0],
                ["put"],
                "ingress",
                [keys.experience(actor), keys.qinc(actor), keys.status(actor), keys.view(actor)],
            ),
            _rule(own[1], ["put"], "egress", [keys.ack(actor), keys.reject(actor)]),
            _rule(own[2], ["liveliness_token"], "ingress", [keys.alive("actor", actor)]),
        ]
        policies.append({"id": actor, "rules": own, "subjects": [actor]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


# With shared memory on, Zenoh hands a large payload to a peer on the same host in a shared-memory segment instead
# of through the link: outside TLS, and readable by whatever can open the segment. A secure run promises that every
# byte travels encrypted, so it is off (which also spares the router mapping every peer's 16 MB segments).
_NO_SHARED_MEMORY = {"enabled": False}


def _tls(files: TlsFiles, side: str) -> dict[str, Any]:
    return {
        "root_ca_certificate": files.ca,
        f"{side}_certificate": files.certificate,
        f"{side}_private_key": files.key,
        "enable_mtls": True,
    }


def router_config(
    listen: Sequence[str],
    tls: TlsFiles,
    credentials_file: str,
    router_password: str,
    rules: dict[str, Any],
    max_message_size: int = MAX_MESSAGE_BYTES,
) -> dict[str, Any]:
    """The router's zenoh configuration: TLS endpoints only, every peer authenticated twice, ``rules`` enforced."""
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "link": {"tls": _tls(tls, "listen"), "rx": {"max_message_size": max_message_size}},
            "auth": {"usrpwd": {"user": ROUTER, "password": router_password, "dictionary_file": credentials_file}},
            "shared_memory": _NO_SHARED_MEMORY,
        },
        "access_control": rules,
    }


def client_config(
    connect: Sequence[str],
    tls: TlsFiles,
    user: str,
    password: str,
    max_message_size: int = MAX_MESSAGE_BYTES,
) -> dict[str, Any]:
    """A learner's, actor's or observer's zenoh configuration: a client of the router, retrying it forever."""
    return {
        "mode": "client",
        "connect": {"endpoints": list(connect), "timeout_ms": -1},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "link": {"tls": _tls(tls, "connect"), "rx": {"max_message_size": max_message_size}},
            "auth": {"usrpwd": {"user": user, "password": password}},
            "shared_memory": _NO_SHARED_MEMORY,
        },
    }


__all__ = [
    "MAX_MESSAGE_BYTES",
    "OBSERVER",
    "ROUTER",
    "TlsFiles",
    "access_control",
    "client_config",
    "router_config",
]
