"""The faults of a chaos run, by name: each one applied to the running cluster returns whether what it expects held,
and its figures; what the checks need later (restarts, kills, spoofed batches) is kept here. A fault sees the run
only through a :class:`Scene` (what it acts on and reads) and a :class:`Cluster` (what it asks of the run while it
acts); :class:`~tools.chaos.run.Chaos` hands over both. Usage::

    faults = Faults(scene, cluster)
    ok, figures = faults.apply["learner-kill"]()

Over 400 lines: one class holds every fault, so that the checks after the run share what the faults kept.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import re
import secrets
import signal
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Protocol, TypeVar

import zenoh

from learner.checkpoint import VersionMark
from protocol import KeySpace, encode
from protocol.security import ROUTER
from sim.formulation import Formulation
from tools.chaos.checks import OVERSIZE_RISE_LIMIT_MB
from tools.chaos.network import Network
from tools.chaos.observe import (
    MALLORY,
    RECOVERY_TIMEOUT_S,
    Observer,
    RssSampler,
    Sighting,
    WaitTimeout,
    live_actors,
    since,
)
from tools.chaos.peers import INTRUDER_TUPLES, REFUSAL_TIMEOUT_MS, SPOOF_PUTS, Peer, Replies, opens, poisoned
from tools.chaos.proxy import Proxies, Shaping
from tools.cluster import Children, Endpoints
from tools.secure import write_secure_set

log = logging.getLogger("tools.chaos")  # one name for the package: its lines read "tools.chaos: ..."

OVERSIZE_BYTES = 160 * 2**20
"""Well past zenoh's message size cap (MAX_MESSAGE_BYTES, 64 MiB + 64 KiB, in every configuration of the project)."""
OVERSIZE_SETTLE_S = 4.0
"""RSS is sampled this long after the put returned: the router may still be reassembling then dropping it."""
STATUS_SETTLE_S = 1.0
"""After a SIGKILL, a status the dead process had already sent still lands within this."""
PARTITION_MARGIN_S = 3.0
"""A partition lasts the zenoh lease plus this: long enough for the router to drop the cut-off session."""
NETWORK_WINDOW_S = 8.0
"""How long the delay and loss faults shape every link."""
DELAY_S = 0.025
"""Added each way on every client's link: 50 ms round trip between a client and the router, 100 ms between an actor
and the learner (through the router)."""
LOSS = 0.02
"""Share of the relayed chunks (up to 64 KiB each) held back one retransmission timeout."""

Fault = Callable[[], tuple[bool, dict[str, Any]]]
T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Scene:
    """What the faults act on and read: the run's processes, its sessions and what chaos observes of it."""

    run_dir: Path
    learner_id: str
    actor_ids: list[str]
    formulation: Formulation
    """What the hostile peers' batches are shaped as."""
    keys: KeySpace
    secure: bool
    lease_s: float
    """Zenoh's session lease: a process silent this long is dropped by the router."""
    children: Children
    endpoints: Endpoints
    observer: Observer
    rss: RssSampler
    network: Network | None
    """The hosts, with network faults in the rotation."""


class Cluster(Protocol):
    """What a fault asks of the run while it acts (a :class:`~tools.chaos.run.Chaos` run is one): a process it
    killed started again as the run started it, the time the latest checkpoint landed, a wait that is given up at
    once if a process of the run exited, and the links' proxies (with network faults, once the hosts are up)."""

    @property
    def proxies(self) -> Proxies | None: ...

    def restart(self, ident: str) -> None: ...

    def checkpoint_mtime(self) -> int: ...

    def wait(self, what: str, timeout: float, probe: Callable[[], T | None]) -> T: ...


class Faults:
    def __init__(self, scene: Scene, cluster: Cluster) -> None:
        self.scene, self.cluster = scene, cluster
        self.restarts: list[dict[str, Any]] = []
        """The figures of each learner restart."""
        self.killed: dict[str, list[dict[str, int]]] = {}
        """Each killed actor's last status counters, per kill."""
        self.spoofed = 0
        """Batches sent under another actor's id."""
        self._victims: dict[str, Iterator[str]] = {
            "actor-stop": itertools.cycle(self.scene.actor_ids),
            "partition": itertools.cycle(self.scene.actor_ids),
            # actor-0 is never killed while there are others: its exact count proves the spoofed tuples were not stored.
            "actor-kill": itertools.cycle(self.scene.actor_ids[1:] or self.scene.actor_ids),
        }
        self.apply: dict[str, Fault] = {
            "learner-kill": self._learner_kill,
            "router-restart": self._router_restart,
            "actor-stop": self._actor_stop,
            "actor-kill": self._actor_kill,
            "partition": self._partition,
            "delay": partial(self._shaped, Shaping(delay_s=DELAY_S)),
            "loss": partial(self._shaped, Shaping(loss=LOSS)),
            "poison": self._poison,
            "spoof": self._spoof,
            "unauthenticated": self._unauthenticated,
            "wrong-certificate": self._wrong_certificate,
            "oversize": self._oversize,
        }

    def hostile(self, plain_id: str) -> str:
        """The id of a hostile peer: the authenticated mallory in a secure run, ``plain_id`` in a plain one."""
        return MALLORY if self.scene.secure else plain_id

    def _learner_kill(self) -> tuple[bool, dict[str, Any]]:
        landed = self.cluster.checkpoint_mtime()
        self.cluster.wait("the next checkpoint", RECOVERY_TIMEOUT_S, lambda: self.cluster.checkpoint_mtime() != landed)
        self.scene.children.kill(self.scene.learner_id)  # at once: the moment with the most state not in any checkpoint
        killed = time.monotonic()
        before = VersionMark(self.scene.run_dir).load()
        starts = len(self._started_versions())
        self.cluster.restart(self.scene.learner_id)
        logged = self.cluster.wait(
            "the resumed learner to start", RECOVERY_TIMEOUT_S, lambda: self._started_versions()[starts:]
        )
        arrived, _ = self.cluster.wait(
            "a status of the resumed learner", RECOVERY_TIMEOUT_S, lambda: self._learner_since(killed)
        )
        seen = self.cluster.wait(
            "a policy of the resumed learner", RECOVERY_TIMEOUT_S, lambda: self.scene.observer.versions(killed)
        )
        figures = {
            "published_before": before,
            "first_version_logged": logged[0],
            "first_version_seen": seen[0],
            "recovered_s": round(arrived - killed, 1),
        }
        self.restarts.append(figures)
        return logged[0] > before and seen[0] > before, figures

    def _started_versions(self) -> list[int]:
        """The version each learner incarnation announced as it started, from its log."""
        text = (self.scene.run_dir / f"{self.scene.learner_id}.log").read_text(errors="replace")
        return [int(v) for v in re.findall(r"started \(policy version (\d+)\)", text)]

    def _learner_since(self, t: float) -> Sighting | None:
        return self.scene.observer.first(self.scene.learner_id, t)

    def _router_restart(self) -> tuple[bool, dict[str, Any]]:
        self.scene.children.kill(ROUTER)
        down = time.monotonic()
        self.cluster.restart(ROUTER)
        back: dict[str, float] = {}
        for sender in (self.scene.learner_id, *self.scene.actor_ids):
            what = f"a status of {sender} through the new router"
            arrived, _ = self.cluster.wait(what, RECOVERY_TIMEOUT_S, partial(self.scene.observer.first, sender, down))
            back[sender] = round(arrived - down, 1)
        return True, {"recovered_s": back[self.scene.learner_id], "status_back_s": back}

    def _live(self, after: float, below: bool) -> Sighting | None:
        """The learner's first status after ``after`` counting fewer live actors than the run has (``below``), or
        all of them."""
        n = len(self.scene.actor_ids)
        return next(
            (s for s in self.scene.observer.sightings(self.scene.learner_id, after) if (live_actors(s) < n) == below),
            None,
        )

    def _full_house(self) -> None:
        """Until the learner counts every actor live (an earlier fault may still be settling), so that the drop a
        fault sees next is its own."""
        self.cluster.wait(
            "the learner to count every actor live", RECOVERY_TIMEOUT_S, partial(self._live, time.monotonic(), False)
        )

    def _actor_stop(self) -> tuple[bool, dict[str, Any]]:
        actor = next(self._victims["actor-stop"])
        self._full_house()
        self.scene.children.signal(actor, signal.SIGSTOP)
        stopped = time.monotonic()
        try:
            # Held until the learner counts it gone: past the lease the router drops the session and its liveliness
            # token goes (seconds later than the lease itself just after a router restart, on loaded cores).
            dropped = self.cluster.wait(
                f"the learner to count {actor} gone", RECOVERY_TIMEOUT_S, lambda: self._live(stopped, below=True)
            )
        finally:
            self.scene.children.signal(actor, signal.SIGCONT)
        resumed = time.monotonic()
        back = self.cluster.wait(
            f"the learner to count {actor} back", RECOVERY_TIMEOUT_S, lambda: self._live(dropped[0], below=False)
        )
        figures = {
            "actor": actor,
            "stopped_s": round(resumed - stopped, 1),
            "live_actors_min": min(
                live_actors(s) for s in self.scene.observer.sightings(self.scene.learner_id, stopped)
            ),
            "gone_after_s": round(dropped[0] - stopped, 1),
            "recovered_s": round(back[0] - resumed, 1),
        }
        return back[0] > resumed, figures  # counted back while still stopped: it never left

    def _actor_kill(self) -> tuple[bool, dict[str, Any]]:
        actor = next(self._victims["actor-kill"])
        born = self.scene.children.started[actor]
        self.scene.children.kill(actor)
        time.sleep(STATUS_SETTLE_S)
        # Its last status: lower bounds of what it had sent and had acknowledged (its outbox is lost by design).
        last = self.scene.observer.latest(actor, born)
        counters = {k: int(last[1].get(k, 0)) if last else 0 for k in ("tuples_sent", "tuples_acked", "visits_acked")}
        self.killed.setdefault(actor, []).append(counters)
        restarted = time.monotonic()
        self.cluster.restart(actor)
        what = f"a status of the new incarnation of {actor}"
        arrived, _ = self.cluster.wait(what, RECOVERY_TIMEOUT_S, lambda: self.scene.observer.first(actor, restarted))
        return True, {"actor": actor, "last_seen": counters, "recovered_s": round(arrived - restarted, 1)}

    def _partition(self) -> tuple[bool, dict[str, Any]]:
        """One actor's host cut off (every packet on its link dropped) past the lease, then healed: the learner
        counts it gone, then back, and its acknowledgements flow again (its outbox re-sends what was cut off)."""
        assert self.scene.network is not None
        actor = next(self._victims["partition"])
        self._full_house()
        last = self.scene.observer.latest(actor)
        resent = int(last[1].get("resent", 0)) if last else 0
        self.scene.network.partition(actor)
        cut = time.monotonic()
        try:
            dropped = self.cluster.wait(
                f"the learner to count {actor} gone", RECOVERY_TIMEOUT_S, lambda: self._live(cut, below=True)
            )
            time.sleep(max(0.0, cut + self.scene.lease_s + PARTITION_MARGIN_S - time.monotonic()))
        finally:
            self.scene.network.heal(actor)
        healed = time.monotonic()
        back = self.cluster.wait(
            f"the learner to count {actor} back", RECOVERY_TIMEOUT_S, lambda: self._live(healed, below=False)
        )
        acked = self._acks_moving(actor, healed)
        figures = {
            "actor": actor,
            "partitioned_s": round(healed - cut, 1),
            "live_actors_min": min(live_actors(s) for s in self.scene.observer.sightings(self.scene.learner_id, cut)),
            "gone_after_s": round(dropped[0] - cut, 1),
            "recovered_s": round(back[0] - healed, 1),
            "acks_resumed_s": round(acked - healed, 1),
            "resent": int((self.scene.observer.latest(actor) or (0.0, {}))[1].get("resent", 0)) - resent,
        }
        return True, figures

    def _acks_moving(self, actor: str, after: float) -> float:
        """When ``actor``'s first status after ``after`` arrived whose acknowledged tuples are above the last seen
        before it."""
        last = self.scene.observer.latest(actor, 0.0)
        before = int(last[1].get("tuples_acked", 0)) if last else 0

        def moved() -> float | None:
            seen = self.scene.observer.sightings(actor, after)
            return next((t for t, c in seen if int(c.get("tuples_acked", 0)) > before), None)

        return self.cluster.wait(f"acknowledgements to {actor} to move", RECOVERY_TIMEOUT_S, moved)

    def _shaped(self, shaping: Shaping) -> tuple[bool, dict[str, Any]]:
        """Every link delayed or lossy for NETWORK_WINDOW_S: the streams must keep flowing (each actor's
        acknowledged tuples rise during it, every actor stays live), and once it is lifted acknowledgements move on."""
        proxies = self.cluster.proxies
        assert proxies is not None
        self._full_house()

        def acked(actor: str) -> int:
            last = self.scene.observer.latest(actor)
            return int(last[1].get("tuples_acked", 0)) if last else 0

        def rate(after: float) -> float:
            rates = [c.get("tuples_per_s", 0.0) for _, c in self.scene.observer.sightings(self.scene.learner_id, after)]
            return round(sum(rates) / len(rates)) if rates else 0.0

        before = {a: acked(a) for a in self.scene.actor_ids}
        relayed_before = sum(d["up"] + d["down"] for d in proxies.relayed().values())
        window_start = time.monotonic()
        rate_before = rate(window_start - NETWORK_WINDOW_S)
        proxies.shape(shaping)
        try:
            time.sleep(NETWORK_WINDOW_S)
        finally:
            proxies.shape(Shaping())
        lifted = time.monotonic()
        during = {a: acked(a) - before[a] for a in self.scene.actor_ids}
        relayed = sum(d["up"] + d["down"] for d in proxies.relayed().values()) - relayed_before
        live_min = min(
            (live_actors(s) for s in self.scene.observer.sightings(self.scene.learner_id, window_start)), default=0
        )
        resumed = max(self._acks_moving(actor, lifted) for actor in self.scene.actor_ids)
        figures = {
            "delay_ms_each_way": round(shaping.delay_s * 1000),
            "loss_per_chunk": shaping.loss,
            "rto_ms": round(shaping.rto_s * 1000),
            "window_s": NETWORK_WINDOW_S,
            "tuples_acked_during": during,
            "learner_tuples_per_s_before": rate_before,
            "learner_tuples_per_s_during": rate(window_start),
            "relayed_mb_during": round(relayed / 1e6, 1),
            "live_actors_min": live_min,
            "recovered_s": round(resumed - lifted, 1),
        }
        return all(n > 0 for n in during.values()) and live_min == len(self.scene.actor_ids), figures

    def _poison(self) -> tuple[bool, dict[str, Any]]:
        ident = self.hostile("poisoner")
        replies = Replies(secrets.randbits(64))  # a new incarnation per round: its seqs start at 0 again
        with Peer(self.scene.endpoints.session(ident), self.scene.keys, ident, self.scene.formulation) as peer:
            peer.listen(replies)
            peer.await_learner()
            peer.put(peer.own_key, encode(peer.batch(0, replies.incarnation)))
            peer.put(peer.own_key, poisoned(peer.batch(1, replies.incarnation)))
            peer.put(peer.own_key, encode(peer.batch(2, replies.incarnation)))
            sent = time.monotonic()
            self.cluster.wait("the Reject of seq 1 and an ack of seq 2", RECOVERY_TIMEOUT_S, lambda: replies.got(1, 2))
        figures = {
            "peer": ident,
            "incarnation": f"{replies.incarnation:x}",
            "rejected_seqs": replies.rejected,
            "reason": replies.reasons[0],
            "acked_seq": replies.acked,
            "recovered_s": since(sent),
        }
        return replies.rejected == [1], figures

    def _spoof(self) -> tuple[bool, dict[str, Any]]:
        ident, target = self.hostile("spoofer"), self.scene.actor_ids[0]
        last = self.scene.observer.latest(self.scene.learner_id)
        before = int(last[1].get("rejected", 0)) if last else 0
        incarnation = secrets.randbits(64)
        with Peer(self.scene.endpoints.session(ident), self.scene.keys, ident, self.scene.formulation) as peer:
            peer.await_learner()
            for seq in range(SPOOF_PUTS):  # the learner must count these as IdentityMismatch and drop them
                peer.put(peer.own_key, encode(peer.batch(seq, incarnation, actor_id=target)))
            # On the genuine actor's key itself: the router's access control must drop them before the learner.
            on_target = SPOOF_PUTS if self.scene.secure else 0
            for seq in range(on_target):
                peer.put(self.scene.keys.experience(target), encode(peer.batch(seq, incarnation, actor_id=target)))
        sent = time.monotonic()
        self.spoofed += SPOOF_PUTS

        def counted() -> int | None:
            seen = self.scene.observer.latest(self.scene.learner_id, sent)
            rise = int(seen[1].get("rejected", 0)) - before if seen else 0
            return rise if rise >= SPOOF_PUTS else None

        rise = self.cluster.wait("the learner to count the lies", RECOVERY_TIMEOUT_S, counted)
        figures = {"peer": ident, "claimed": target, "lies_on_own_key": SPOOF_PUTS, "puts_on_claimed_key": on_target}
        return True, {**figures, "learner_rejected_rise": rise, "recovered_s": since(sent)}

    def _unauthenticated(self) -> tuple[bool, dict[str, Any]]:
        conf = self.scene.endpoints.client_dict(MALLORY)
        del conf["transport"]["auth"]  # a valid certificate, no password
        return self._refused(conf)

    def _wrong_certificate(self) -> tuple[bool, dict[str, Any]]:
        with tempfile.TemporaryDirectory(prefix="chaos-other-ca-") as other:
            assert self.scene.endpoints.secure is not None
            foreign = dataclasses.replace(self.scene.endpoints.secure, folder=Path(other), actor_ids=(MALLORY,))
            write_secure_set(foreign)  # another CA, and a mallory certificate signed by it
            conf = self.scene.endpoints.client_dict(MALLORY)  # the genuine password: only the certificate is wrong
            tls = conf["transport"]["link"]["tls"]
            tls["connect_certificate"], tls["connect_private_key"] = (
                str(foreign.folder / f"{MALLORY}.pem"),
                str(foreign.folder / f"{MALLORY}.key"),
            )
            return self._refused(conf)

    def _refused(self, conf: dict[str, Any]) -> tuple[bool, dict[str, Any]]:
        """Whether a session with ``conf`` is refused. One that opens puts a batch where the genuine mallory may,
        and the checks find it if it was stored. The genuine mallory connects first: a refusal below is then the
        router's judgement, not an outage (the fault holds only if it did)."""
        control = opens(self.scene.endpoints.client_dict(MALLORY))
        conf["connect"]["timeout_ms"] = REFUSAL_TIMEOUT_MS
        started = time.monotonic()
        try:
            with Peer(
                zenoh.Config.from_json5(json.dumps(conf)), self.scene.keys, MALLORY, self.scene.formulation
            ) as peer:
                peer.put(peer.own_key, encode(peer.batch(0, secrets.randbits(64), n=INTRUDER_TUPLES)))
                time.sleep(STATUS_SETTLE_S)
        except zenoh.ZError as exc:
            error = str(exc).split(" at ")[0]  # zenoh appends the Rust source location
            return control, {"refused": True, "control_opened": control, "error": error, "refused_s": since(started)}
        log.warning("a session that should have been refused opened; it put %d tuples as mallory", INTRUDER_TUPLES)
        return control, {"refused": False, "control_opened": control}

    def _oversize(self) -> tuple[bool, dict[str, Any]]:
        ident = self.hostile("oversizer")
        watched = (ROUTER, self.scene.learner_id)
        before = self.scene.rss.measure(watched)
        with Peer(self.scene.endpoints.session(ident), self.scene.keys, ident, self.scene.formulation) as peer:
            peer.await_learner()
            peak, put_s = self._peak_rss_while(watched, lambda: peer.put(peer.own_key, bytes(OVERSIZE_BYTES)))
        after = time.monotonic()
        arrived, _ = self.cluster.wait(
            "a learner status after the oversize put", RECOVERY_TIMEOUT_S, lambda: self._learner_since(after)
        )
        rise = {name: round(peak.get(name, 0.0) - before.get(name, 0.0), 1) for name in watched}
        up = self.scene.learner_id in self.scene.children.running()
        figures = {
            "peer": ident,
            "bytes": OVERSIZE_BYTES,
            "put_s": put_s,
            "rss_before_mb": before,
            "rss_peak_mb": peak,
            "rss_rise_mb": rise,
            "learner_up": up,
            "recovered_s": round(arrived - after, 1),
        }
        return up and all(r < OVERSIZE_RISE_LIMIT_MB for r in rise.values()), figures

    def _peak_rss_while(self, names: tuple[str, ...], action: Callable[[], None]) -> tuple[dict[str, float], float]:
        """Run ``action`` on a thread, sampling ``names``' RSS every 0.25 s until OVERSIZE_SETTLE_S after it ended:
        the peaks, and how long it took."""
        errors: list[zenoh.ZError] = []

        def act() -> None:
            try:
                action()
            except zenoh.ZError as exc:
                errors.append(exc)

        worker = threading.Thread(target=act, name="oversize-put", daemon=True)
        started, peak = time.monotonic(), self.scene.rss.measure(names)
        worker.start()
        ended: float | None = None
        while ended is None or time.monotonic() - ended < OVERSIZE_SETTLE_S:
            time.sleep(0.25)
            for name, mb in self.scene.rss.measure(names).items():
                peak[name] = max(peak.get(name, 0.0), mb)
            if ended is None and not worker.is_alive():
                ended = time.monotonic()
            if ended is None and time.monotonic() - started > RECOVERY_TIMEOUT_S:
                raise WaitTimeout(f"the {OVERSIZE_BYTES} B put still blocked after {RECOVERY_TIMEOUT_S:.0f} s")
        if errors:
            raise errors[0]
        return peak, round(ended - started, 1)
