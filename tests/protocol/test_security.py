"""The secure set on real zenoh sessions: a router with the generated configuration and clients with theirs.

The deny paths are what matter (an allow-all mistake passes every allow test): each identity tries every key it
must not use; peers without a password, with another CA's certificate or over plain TCP never connect; a peer with
one identity's certificate and another's password connects (zenoh checks the two independently) and is denied
every message, both ways.
"""

from __future__ import annotations

import copy
import json
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from protocol import KeySpace, zenoh_config
from protocol.security import MAX_MESSAGE_BYTES
from tools.secure import SecureSet, write_secure_set
from tools.system import free_port

ACTORS = ("actor-0", "actor-1")
KEYS = KeySpace("sec")


@pytest.fixture(scope="module")
def secure_set(tmp_path_factory: pytest.TempPathFactory) -> SecureSet:
    port = free_port()
    spec = SecureSet(
        folder=tmp_path_factory.mktemp("secure"),
        actor_ids=ACTORS,
        namespace=KEYS.namespace,
        listen=(f"tls/127.0.0.1:{port}",),
        connect=(f"tls/localhost:{port}",),
    )
    write_secure_set(spec)
    return spec


def _conf(spec: SecureSet, ident: str) -> zenoh.Config:
    return zenoh.Config.from_file(str(spec.config(ident)))


def _document(path: Path) -> dict[str, Any]:
    text = path.read_text()
    return dict(json.loads(text[text.index("\n") + 1 :]))  # after the header comment


def _from_document(doc: dict[str, Any]) -> zenoh.Config:
    conf = zenoh.Config()
    for key, value in doc.items():
        conf.insert_json5(key, json.dumps(value))
    return conf


class Inbox:
    """Payloads each identity received, by key."""

    def __init__(self) -> None:
        self.got: dict[str, list[tuple[str, bytes]]] = {}
        self._lock = threading.Lock()

    def handler(self, who: str) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:
            with self._lock:
                self.got.setdefault(who, []).append((str(sample.key_expr), sample.payload.to_bytes()))

        return on_sample

    def of(self, who: str) -> list[tuple[str, bytes]]:
        with self._lock:
            return list(self.got.get(who, []))


def _wait(predicate: Callable[[], bool], timeout: float = 30.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return False


@pytest.fixture(scope="module")
def router(secure_set: SecureSet) -> Iterator[zenoh.Session]:
    with zenoh.open(_conf(secure_set, "router")) as session:
        yield session


@pytest.fixture(scope="module")
def cluster(secure_set: SecureSet, router: zenoh.Session) -> Iterator[dict[str, zenoh.Session]]:
    sessions = {ident: zenoh.open(_conf(secure_set, ident)) for ident in ("learner", *ACTORS, "observer")}
    try:
        yield sessions
    finally:
        for session in sessions.values():
            session.close()


def test_each_identity_publishes_and_receives_only_what_the_rules_allow(cluster: dict[str, zenoh.Session]) -> None:
    inbox = Inbox()
    # Everyone subscribes to everything: what arrives is what the router's egress rules let through.
    subs = [s.declare_subscriber(f"{KEYS.root}/**", inbox.handler(who)) for who, s in cluster.items()]
    time.sleep(1.0)  # the declarations reach the router; a put before that would go nowhere for everyone alike
    # Each identity's own keys first, then keys it has no right to.
    attempts = {
        "learner": [
            *(KEYS.policy(), KEYS.ack("actor-0"), KEYS.reject("actor-1"), KEYS.status("learner")),
            *(KEYS.experience("actor-0"), KEYS.qinc("actor-1"), KEYS.status("actor-0")),
        ],
        "actor-0": [
            *(KEYS.experience("actor-0"), KEYS.qinc("actor-0"), KEYS.status("actor-0")),
            *(KEYS.experience("actor-1"), KEYS.qinc("actor-1"), KEYS.policy(), KEYS.ack("actor-0"), KEYS.status("x")),
        ],
        "observer": [KEYS.experience("observer"), KEYS.policy(), KEYS.status("observer")],
    }
    for who, keys in attempts.items():
        for key in keys:
            cluster[who].put(key, who.encode())
    # The last allowed put of each kind has arrived once this holds (one router, in-order per link).
    assert _wait(lambda: len(inbox.of("observer")) >= 2 and len(inbox.of("actor-1")) >= 2)
    time.sleep(1.0)  # and anything wrongly allowed would have arrived by now as well
    for sub in subs:
        sub.undeclare()

    def remote(who: str) -> set[tuple[str, str]]:
        return {(key.removeprefix(KEYS.root + "/"), payload.decode()) for key, payload in inbox.of(who)} - {
            (key.removeprefix(KEYS.root + "/"), who) for key in attempts.get(who, [])
        }  # minus the session's own puts, delivered locally

    assert remote("learner") == {("experience/actor-0", "actor-0"), ("qinc/actor-0", "actor-0")}
    assert remote("actor-0") == {("policy", "learner"), ("ack/actor-0", "learner")}
    assert remote("actor-1") == {("policy", "learner"), ("reject/actor-1", "learner")}
    assert remote("observer") == {("policy", "learner"), ("status/learner", "learner"), ("status/actor-0", "actor-0")}


def _serve(answer: bytes) -> Callable[[zenoh.Query], None]:
    def on_query(query: zenoh.Query) -> None:
        with query:
            query.reply(KEYS.policy_latest(), answer)

    return on_query


def test_only_the_learner_serves_the_policy(cluster: dict[str, zenoh.Session]) -> None:
    queryables = [
        cluster["learner"].declare_queryable(KEYS.policy_latest(), _serve(b"genuine")),
        cluster["actor-1"].declare_queryable(KEYS.policy_latest(), _serve(b"forged")),
    ]
    answers: dict[str, list[bytes]] = {"actor-0": [], "observer": []}

    def genuine_answer(asker: str) -> bool:
        # Asked again until the learner's queryable has reached the router; every answer is kept and checked.
        got = [r.ok.payload.to_bytes() for r in cluster[asker].get(KEYS.policy_latest(), timeout=5) if r.ok]
        answers[asker] += got
        return b"genuine" in got

    try:
        assert _wait(lambda: genuine_answer("actor-0")) and _wait(lambda: genuine_answer("observer"))
    finally:
        for queryable in queryables:
            queryable.undeclare()
    assert set(answers["actor-0"]) == {b"genuine"} and set(answers["observer"]) == {b"genuine"}


@pytest.mark.parametrize(
    ("declarer", "forged", "own"),
    [
        ("actor-1", KEYS.alive("actor", "actor-0"), KEYS.alive("actor", "actor-1")),
        ("actor-0", KEYS.alive("learner", "learner"), KEYS.alive("actor", "actor-0")),
    ],
)
def test_only_its_own_liveliness_token_reaches_the_learner(
    declarer: str, forged: str, own: str, cluster: dict[str, zenoh.Session]
) -> None:
    """A token on another's key is declared first, then the declarer's own: once the own one has arrived, the forged
    one, sent earlier on the same link, would have too. Only the forged key is checked for: the router may still
    report a token of the previous case while its undeclaration is on the way."""
    seen: list[str] = []
    watch = (
        cluster["learner"]
        .liveliness()
        .declare_subscriber(f"{KEYS.root}/alive/**", lambda s: seen.append(str(s.key_expr)), history=True)
    )
    tokens = [cluster[declarer].liveliness().declare_token(key) for key in (forged, own)]
    try:
        assert _wait(lambda: own in seen)
    finally:
        for handle in [*tokens, watch]:
            handle.undeclare()
    assert forged not in seen and own in seen


@pytest.mark.parametrize("case", ["no password", "wrong password", "other CA", "plain TCP"])
def test_a_peer_that_cannot_prove_its_identity_never_connects(
    case: str, secure_set: SecureSet, cluster: dict[str, zenoh.Session], tmp_path: Path
) -> None:
    doc = _document(secure_set.config("actor-0"))
    if case == "no password":
        del doc["transport"]["auth"]
    elif case == "wrong password":
        doc["transport"]["auth"]["usrpwd"]["password"] = "guess"
    elif case == "other CA":
        other = SecureSet(folder=tmp_path / "other", actor_ids=ACTORS, namespace=KEYS.namespace)
        write_secure_set(other)
        doc = _document(other.config("actor-0"))
        doc["connect"] = copy.deepcopy(_document(secure_set.config("actor-0"))["connect"])
    else:
        doc["connect"]["endpoints"] = [e.replace("tls/localhost", "tcp/127.0.0.1") for e in doc["connect"]["endpoints"]]
    doc["connect"]["timeout_ms"] = 3000
    # The router is up (the cluster's sessions are its clients): the refusal is its judgement, not an outage.
    assert cluster["actor-0"].info.routers_zid()
    with pytest.raises(zenoh.ZError, match="Unable to connect"), zenoh.open(_from_document(doc)):
        pass


def test_one_identitys_certificate_with_anothers_password_connects_and_is_denied_everything(
    secure_set: SecureSet, router: zenoh.Session, cluster: dict[str, zenoh.Session]
) -> None:
    """Zenoh 1.10.2 checks the certificate (TLS) and the password (usrpwd) each on its own and has no setting that
    ties one to the other, so the session opens. Every access-control subject needs both to name one identity, so
    it matches none, and the router's default (deny) applies to every message it sends or would be sent: it puts
    nowhere, hears nothing, gets no answer, and its tokens reach nobody. Each check has a genuine control."""
    doc = _document(secure_set.config("actor-0"))  # actor-0's user name and password ...
    tls = doc["transport"]["link"]["tls"]
    for field in ("connect_certificate", "connect_private_key"):
        tls[field] = tls[field].replace("actor-0", "actor-1")  # ... with actor-1's certificate and key
    doc["connect"]["timeout_ms"] = 10_000
    inbox = Inbox()
    tokens_seen: list[tuple[str, str]] = []
    undeclare = [s.declare_subscriber(f"{KEYS.root}/**", inbox.handler(who)) for who, s in cluster.items()]
    undeclare.append(  # no history: a token of an earlier test may still be on its way out
        cluster["observer"]
        .liveliness()
        .declare_subscriber(f"{KEYS.root}/alive/**", lambda s: tokens_seen.append((str(s.kind), str(s.key_expr))))
    )
    undeclare.append(cluster["learner"].declare_queryable(KEYS.policy_latest(), _serve(b"genuine")))
    with zenoh.open(_from_document(doc)) as mixed:
        # The router sees the certificate's identity on the link; the password's is in no API.
        assert [link.auth_identifier for link in router.info.links() if link.zid == mixed.zid()] == ["actor-1"]
        heard = Inbox()
        mixed_tokens: list[str] = []
        handles = [
            mixed.declare_subscriber(f"{KEYS.root}/**", heard.handler("mixed")),
            mixed.liveliness().declare_subscriber(
                f"{KEYS.root}/alive/**", lambda s: mixed_tokens.append(str(s.key_expr)), history=True
            ),
            *(mixed.liveliness().declare_token(KEYS.alive("actor", a)) for a in ACTORS),
            mixed.declare_queryable(KEYS.policy_latest(), _serve(b"forged")),
        ]
        time.sleep(1.0)  # its declarations reach the router, as the cluster's did
        for key in (KEYS.experience("actor-0"), KEYS.experience("actor-1"), KEYS.qinc("actor-0"), KEYS.policy()):
            mixed.put(key, b"mixed")
        mixed.put(KEYS.status("actor-1"), b"mixed")
        # What it would receive if allowed, each delivered to a genuine control.
        cluster["learner"].put(KEYS.policy(), b"learner")
        cluster["learner"].put(KEYS.ack("actor-0"), b"learner")
        cluster["learner"].put(KEYS.ack("actor-1"), b"learner")
        cluster["actor-0"].put(KEYS.experience("actor-0"), b"actor-0")
        token = cluster["learner"].liveliness().declare_token(KEYS.alive("learner", "learner"))
        genuine = [r.ok.payload.to_bytes() for r in cluster["actor-0"].get(KEYS.policy_latest(), timeout=5) if r.ok]
        asked = [r.ok.payload.to_bytes() for r in mixed.get(KEYS.policy_latest(), timeout=2) if r.ok]
        assert _wait(lambda: len(inbox.of("actor-0")) >= 1 and len(inbox.of("actor-1")) >= 1)
        assert _wait(lambda: len(inbox.of("observer")) >= 1 and len(inbox.of("learner")) >= 1)
        assert _wait(lambda: ("SampleKind.PUT", KEYS.alive("learner", "learner")) in tokens_seen)
        time.sleep(1.0)  # anything wrongly allowed, sent before the controls on the same links, is in by now
        token.undeclare()
        for handle in [*handles, *undeclare]:
            handle.undeclare()
    assert set(genuine) == {b"genuine"}  # its forged answer reached nobody ...
    assert asked == [b"forged"]  # ... and the learner's did not reach it: only its own, answered locally
    assert {payload for who in cluster for _, payload in inbox.of(who)} == {b"learner", b"actor-0"}
    assert {payload for _, payload in heard.of("mixed")} <= {b"mixed"}  # its own puts only, delivered locally
    assert KEYS.alive("learner", "learner") not in mixed_tokens
    assert not [key for kind, key in tokens_seen if kind == "SampleKind.PUT" and "/alive/actor/" in key]


def test_files_are_private_certificates_verify_and_nothing_secret_is_logged(
    secure_set: SecureSet, caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

    folder = secure_set.folder
    assert folder.stat().st_mode & 0o777 == 0o700
    for path in folder.iterdir():
        mode = path.stat().st_mode & 0o777
        assert mode == (0o644 if path.suffix == ".pem" else 0o600), path.name
    ca = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
    ca_key = ca.public_key()
    assert isinstance(ca_key, ec.EllipticCurvePublicKey)
    for ident in ("router", "learner", *ACTORS, "observer"):
        cert = x509.load_pem_x509_certificate((folder / f"{ident}.pem").read_bytes())
        cert.verify_directly_issued_by(ca)
        assert cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)[0].value == ident
        assert not cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    router = x509.load_pem_x509_certificate((folder / "router.pem").read_bytes())
    names = router.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in names.get_values_for_type(x509.DNSName)
    # The router's dictionary holds every client identity, each with its own password.
    lines = dict(line.split(":", 1) for line in (folder / "credentials.txt").read_text().splitlines())
    assert set(lines) == {"learner", *ACTORS, "observer"} and len(set(lines.values())) == len(lines)
    # A fresh set written while logging is captured: no password or key material in any record.
    caplog.set_level("DEBUG")
    again = SecureSet(folder=tmp_path / "again", actor_ids=ACTORS)
    write_secure_set(again)
    secrets = (again.folder / "credentials.txt").read_text().split()
    text = caplog.text
    assert caplog.records and all(s.split(":", 1)[1] not in text for s in secrets) and "PRIVATE KEY" not in text


def test_zenoh_drops_a_message_over_the_protocol_limit_while_reassembling_it() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    got: list[int] = []
    receiver_conf = zenoh_config(listen=[endpoint])
    assert int(receiver_conf.get_json("transport/link/rx/max_message_size")) == MAX_MESSAGE_BYTES
    with zenoh.open(receiver_conf) as receiver, zenoh.open(zenoh_config(connect=[endpoint])) as sender:
        sub = receiver.declare_subscriber("big/*", lambda s: got.append(len(s.payload.to_bytes())))
        publisher = sender.declare_publisher("big/x", congestion_control=zenoh.CongestionControl.BLOCK)
        assert _wait(lambda: bool(publisher.matching_status.matching))
        publisher.put(b"a" * 1000)
        publisher.put(bytes(MAX_MESSAGE_BYTES + 1024 * 1024))
        publisher.put(b"b" * 10)  # the link survives the dropped message
        assert _wait(lambda: 10 in got)
        publisher.undeclare()
        sub.undeclare()
    assert got == [1000, 10]


def test_a_client_configured_from_docs_protocol_section_8_alone_delivers(
    secure_set: SecureSet, cluster: dict[str, zenoh.Session]
) -> None:
    """The settings docs/reference/protocol.md §8 lists for a client, written by hand (not secure init's file): its own
    certificate, key and password, the CA, the router's TLS endpoint."""
    folder = secure_set.folder
    password = dict(line.split(":", 1) for line in (folder / "credentials.txt").read_text().splitlines())["actor-1"]
    conf = zenoh.Config()
    settings = {
        "mode": "client",
        "connect/endpoints": list(secure_set.connect),
        "connect/timeout_ms": 10_000,
        "scouting/multicast/enabled": False,
        "transport/link/tls/root_ca_certificate": str(folder / "ca.pem"),
        "transport/link/tls/connect_certificate": str(folder / "actor-1.pem"),
        "transport/link/tls/connect_private_key": str(folder / "actor-1.key"),
        "transport/link/tls/enable_mtls": True,
        "transport/auth/usrpwd/user": "actor-1",
        "transport/auth/usrpwd/password": password,
        "transport/shared_memory/enabled": False,
    }
    for key, value in settings.items():
        conf.insert_json5(key, json.dumps(value))
    got: list[bytes] = []
    sub = cluster["learner"].declare_subscriber(KEYS.experience("*"), lambda s: got.append(s.payload.to_bytes()))
    try:
        with zenoh.open(conf) as client:
            publisher = client.declare_publisher(KEYS.experience("actor-1"))
            assert _wait(lambda: bool(publisher.matching_status.matching))
            publisher.put(b"by the document")
            client.put(KEYS.experience("actor-0"), b"not its key")
            assert _wait(lambda: b"by the document" in got)
            time.sleep(0.5)
            publisher.undeclare()
    finally:
        sub.undeclare()
    assert got == [b"by the document"]
