"""One chaos run (:class:`Chaos`): the cluster started, the faults applied in rotation (each returns whether what it
expects held, and its figures), then the drain and the figures with the checks."""

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
from functools import partial
from pathlib import Path
from typing import Any, TypeVar

import zenoh

from ennc_ql.chaos.checks import OVERSIZE_RISE_LIMIT_MB, Evidence, figures_and_checks
from ennc_ql.chaos.cluster import (
    MALLORY,
    RECOVERY_TIMEOUT_S,
    Children,
    Observer,
    RssSampler,
    Sighting,
    WaitTimeout,
    last_json,
    listening,
    live_actors,
    make_wiring,
    since,
    wait_for,
)
from ennc_ql.chaos.options import ChaosOptions
from ennc_ql.chaos.peers import INTRUDER_TUPLES, REFUSAL_TIMEOUT_MS, SPOOF_PUTS, Peer, Replies, opens, poisoned
from ennc_ql.launch import ACTOR_NICENESS, UpConfig, child_configs, write_configs
from ennc_ql.secure import write_secure_set
from learner.checkpoint import CHECKPOINT, VersionMark
from protocol import KeySpace, encode
from protocol.security import OBSERVER, ROUTER

log = logging.getLogger("ennc_ql.chaos")  # one name for the package: its lines read "ennc_ql.chaos: ..."

OVERSIZE_BYTES = 160 * 2**20
"""Well past zenoh's message size cap (MAX_MESSAGE_BYTES, 64 MiB + 64 KiB, in every configuration of the project)."""
OVERSIZE_SETTLE_S = 4.0
"""RSS is sampled this long after the put returned: the router may still be reassembling then dropping it."""

FIRST_POLICY_TIMEOUT_S = 900.0
"""Phase 1 with the default budget takes minutes on a busy two-core machine."""
ACTOR_STOP_MARGIN_S = 60.0
"""An actor stops after its current trial and its outbox flush (``--actor-flush-timeout``) plus this."""
LEARNER_STOP_S = 600.0
"""The learner's final evaluation (``--learner-final-eval-trials``) and report may take minutes."""
STATUS_SETTLE_S = 1.0
"""After a SIGKILL, a status the dead process had already sent still lands within this."""

T = TypeVar("T")


class Chaos:
    """One chaos run: the cluster, the faults in rotation, the drain, the figures. Usage::

    out = Chaos(options, config, run_dir, run_id, namespace).run()   # the JSON object ``--json`` prints
    """

    def __init__(self, options: ChaosOptions, config: UpConfig, run_dir: Path, run_id: str, namespace: str) -> None:
        self.options = options
        self.run_dir = run_dir
        self.run_id = run_id
        self.keys = KeySpace(namespace)
        self.learner, self.actors = child_configs(config)
        self.learner_id = self.learner.learner_id
        self.actor_ids = [a.actor_id for a in self.actors]
        self.formulation = self.learner.resolved
        self.wiring = make_wiring(run_dir, namespace, self.learner_id, self.actor_ids, options.secure)
        self.lease_s = int(self.wiring.session(OBSERVER).get_json("transport/link/tx/lease")) / 1000
        self.t0 = time.monotonic()
        self.children = Children(run_dir)
        self.observer = Observer()
        self.rss = RssSampler(self.children, options.rss_interval, self.t0)
        self.records: list[dict[str, Any]] = []
        self.restarts: list[dict[str, Any]] = []
        self.killed: dict[str, list[dict[str, int]]] = {}
        self.spoofed = 0
        self._victims: dict[str, Iterator[str]] = {
            "actor-stop": itertools.cycle(self.actor_ids),
            # actor-0 is never killed while there are others: its exact count proves the spoofed tuples were not stored.
            "actor-kill": itertools.cycle(self.actor_ids[1:] or self.actor_ids),
        }
        self._faults: dict[str, Callable[[], tuple[bool, dict[str, Any]]]] = {
            "learner-kill": self._learner_kill,
            "router-restart": self._router_restart,
            "actor-stop": self._actor_stop,
            "actor-kill": self._actor_kill,
            "poison": self._poison,
            "spoof": self._spoof,
            "unauthenticated": self._unauthenticated,
            "wrong-certificate": self._wrong_certificate,
            "oversize": self._oversize,
        }
        write_configs(config, self.learner, self.actors, run_dir)

    def run(self) -> dict[str, Any]:
        """Start the cluster, apply the faults, drain it and return the figures with the checks; every child is
        killed on the way out, whatever happened (an exception, Ctrl-C)."""
        try:
            self.children.start(ROUTER, ["router", *self.wiring.router_flags()])
            # The observer's zenoh.open would wait for the router forever (clients retry it without end).
            self._wait("the router to listen", RECOVERY_TIMEOUT_S, lambda: listening(self.wiring.port))
            with self.observer.watching(self.wiring.session(OBSERVER), self.keys):
                self.children.start(self.learner_id, self._learner_argv(resume=False))
                for actor in self.actor_ids:
                    self.children.start(actor, self._actor_argv(actor), nice=ACTOR_NICENESS)
                self.rss.start()
                try:
                    self._rotate_faults()
                finally:
                    self.rss.stop()
                finals, codes = self._drain()
        finally:
            self.children.close()
        return self._results(finals, codes)

    def _learner_argv(self, resume: bool) -> list[str]:
        argv = ["learner", "--config", str(self.run_dir / "learner.toml"), "--run-dir", str(self.run_dir), "--json"]
        return [*argv, *self.wiring.client_flags(self.learner_id), *(["--resume"] if resume else [])]

    def _actor_argv(self, actor: str) -> list[str]:
        return ["actor", "--config", str(self.run_dir / f"{actor}.toml"), "--json", *self.wiring.client_flags(actor)]

    def _rotate_faults(self) -> None:
        """Once the first policy is checkpointed, one fault every ``fault_interval`` s in rotation: a whole round at
        least, then until the duration is over; the run then goes on to the end of the duration."""
        if not self._await_first_policy():
            return
        self.rss.baseline = self.rss.sample()
        deadline = self.t0 + self.options.duration
        due = time.monotonic()
        for applied, name in enumerate(itertools.cycle(self.options.faults)):
            if applied >= len(self.options.faults) and max(due, time.monotonic()) >= deadline:
                break
            dead = self.children.exited()
            if dead:  # a fault would only wait for it in vain; the processes check reports it
                log.error(
                    "%s exited: no more faults; the log of %s ends:\n%s", dead, dead[0], self.children.tail(dead[0])
                )
                return
            time.sleep(max(0.0, due - time.monotonic()))
            due = time.monotonic() + self.options.fault_interval
            self.records.append(self._apply(name))
        time.sleep(max(0.0, deadline - time.monotonic()))

    def _await_first_policy(self) -> bool:
        """Until a policy was broadcast and a checkpoint holding it landed (so a killed learner resumes with it)."""
        try:
            self._wait("a first policy", FIRST_POLICY_TIMEOUT_S, lambda: self.observer.versions())
            broadcast = time.time_ns()
            self._wait("a checkpoint of it", RECOVERY_TIMEOUT_S, lambda: self._checkpoint_mtime() > broadcast)
        except WaitTimeout as exc:
            log.error("no fault applied: %s; the learner's log ends:\n%s", exc, self.children.tail(self.learner_id))
            return False
        log.info("first policy v%d checkpointed at t=%.0fs: faults begin", self.observer.versions()[0], self._t())
        return True

    def _t(self) -> float:
        return round(time.monotonic() - self.t0, 1)

    def _wait(self, what: str, timeout: float, probe: Callable[[], T | None]) -> T:
        """:func:`wait_for`, given up at once if a process of the run exited meanwhile (nothing would come)."""

        def probe_alive() -> T | None:
            dead = self.children.exited()
            if dead:
                raise WaitTimeout(f"{', '.join(dead)} exited while chaos waited for {what}")
            return probe()

        return wait_for(what, timeout, probe_alive)

    def _apply(self, name: str) -> dict[str, Any]:
        t = self._t()
        log.info("fault %s at t=%.0fs", name, t)
        try:
            ok, figures = self._faults[name]()
        except (WaitTimeout, zenoh.ZError) as exc:
            ok, figures = False, {"error": str(exc)}
        record = {"name": name, "t_s": t, "ok": ok, **figures}
        (log.info if ok else log.error)("fault %s %s: %s", name, "held" if ok else "FAILED", json.dumps(figures))
        return record

    # -- the faults (each returns whether what it expects held, and its figures) ------------------------------------

    def _learner_kill(self) -> tuple[bool, dict[str, Any]]:
        landed = self._checkpoint_mtime()
        self._wait("the next checkpoint", RECOVERY_TIMEOUT_S, lambda: self._checkpoint_mtime() != landed)
        self.children.kill(self.learner_id)  # at once: the moment with the most state not in any checkpoint
        killed = time.monotonic()
        before = VersionMark(self.run_dir).load()
        starts = len(self._started_versions())
        self.children.start(self.learner_id, self._learner_argv(resume=True))
        logged = self._wait(
            "the resumed learner to start", RECOVERY_TIMEOUT_S, lambda: self._started_versions()[starts:]
        )
        arrived, _ = self._wait(
            "a status of the resumed learner", RECOVERY_TIMEOUT_S, lambda: self._learner_since(killed)
        )
        seen = self._wait("a policy of the resumed learner", RECOVERY_TIMEOUT_S, lambda: self.observer.versions(killed))
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
        text = (self.run_dir / f"{self.learner_id}.log").read_text(errors="replace")
        return [int(v) for v in re.findall(r"started \(policy version (\d+)\)", text)]

    def _checkpoint_mtime(self) -> int:
        path = self.run_dir / CHECKPOINT
        return path.stat().st_mtime_ns if path.exists() else 0

    def _learner_since(self, t: float) -> Sighting | None:
        return self.observer.first(self.learner_id, t)

    def _router_restart(self) -> tuple[bool, dict[str, Any]]:
        self.children.kill(ROUTER)
        down = time.monotonic()
        self.children.start(ROUTER, ["router", *self.wiring.router_flags()])
        back: dict[str, float] = {}
        for sender in (self.learner_id, *self.actor_ids):
            what = f"a status of {sender} through the new router"
            arrived, _ = self._wait(what, RECOVERY_TIMEOUT_S, partial(self.observer.first, sender, down))
            back[sender] = round(arrived - down, 1)
        return True, {"recovered_s": back[self.learner_id], "status_back_s": back}

    def _actor_stop(self) -> tuple[bool, dict[str, Any]]:
        actor = next(self._victims["actor-stop"])
        pause = self.lease_s + 3.0
        n = len(self.actor_ids)

        def live(after: float, below: bool) -> Sighting | None:
            return next(
                (s for s in self.observer.sightings(self.learner_id, after) if (live_actors(s) < n) == below), None
            )

        # From a full house (an earlier fault may still be settling), so the drop seen next is this stop's.
        self._wait("the learner to count every actor live", RECOVERY_TIMEOUT_S, partial(live, time.monotonic(), False))
        self.children.signal(actor, signal.SIGSTOP)
        stopped = time.monotonic()
        try:
            time.sleep(pause)  # past the lease: the router drops the session and its liveliness token goes
        finally:
            self.children.signal(actor, signal.SIGCONT)
        resumed = time.monotonic()
        dropped = self._wait(
            f"the learner to count {actor} gone", RECOVERY_TIMEOUT_S, lambda: live(stopped, below=True)
        )
        back = self._wait(
            f"the learner to count {actor} back", RECOVERY_TIMEOUT_S, lambda: live(dropped[0], below=False)
        )
        figures = {
            "actor": actor,
            "stopped_s": pause,
            "live_actors_min": min(live_actors(s) for s in self.observer.sightings(self.learner_id, stopped)),
            "gone_after_s": round(dropped[0] - stopped, 1),
            "recovered_s": round(back[0] - resumed, 1),
        }
        return back[0] > resumed, figures  # counted back while still stopped: it never left

    def _actor_kill(self) -> tuple[bool, dict[str, Any]]:
        actor = next(self._victims["actor-kill"])
        born = self.children.started[actor]
        self.children.kill(actor)
        time.sleep(STATUS_SETTLE_S)
        # Its last status: lower bounds of what it had sent and had acknowledged (its outbox is lost by design).
        last = self.observer.latest(actor, born)
        counters = {k: int(last[1].get(k, 0)) if last else 0 for k in ("tuples_sent", "tuples_acked", "visits_acked")}
        self.killed.setdefault(actor, []).append(counters)
        restarted = time.monotonic()
        self.children.start(actor, self._actor_argv(actor), nice=ACTOR_NICENESS)
        what = f"a status of the new incarnation of {actor}"
        arrived, _ = self._wait(what, RECOVERY_TIMEOUT_S, lambda: self.observer.first(actor, restarted))
        return True, {"actor": actor, "last_seen": counters, "recovered_s": round(arrived - restarted, 1)}

    def _poison(self) -> tuple[bool, dict[str, Any]]:
        ident = self.wiring.hostile("poisoner")
        replies = Replies(secrets.randbits(64))  # a new incarnation per round: its seqs start at 0 again
        with Peer(self.wiring.session(ident), self.keys, ident, self.formulation) as peer:
            peer.listen(replies)
            peer.await_learner()
            peer.put(peer.own_key, encode(peer.batch(0, replies.incarnation)))
            peer.put(peer.own_key, poisoned(peer.batch(1, replies.incarnation)))
            peer.put(peer.own_key, encode(peer.batch(2, replies.incarnation)))
            sent = time.monotonic()
            self._wait("the Reject of seq 1 and an ack of seq 2", RECOVERY_TIMEOUT_S, lambda: replies.got(1, 2))
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
        ident, target = self.wiring.hostile("spoofer"), self.actor_ids[0]
        last = self.observer.latest(self.learner_id)
        before = int(last[1].get("rejected", 0)) if last else 0
        incarnation = secrets.randbits(64)
        with Peer(self.wiring.session(ident), self.keys, ident, self.formulation) as peer:
            peer.await_learner()
            for seq in range(SPOOF_PUTS):  # the learner must count these as IdentityMismatch and drop them
                peer.put(peer.own_key, encode(peer.batch(seq, incarnation, actor_id=target)))
            # On the genuine actor's key itself: the router's access control must drop them before the learner.
            on_target = SPOOF_PUTS if self.options.secure else 0
            for seq in range(on_target):
                peer.put(self.keys.experience(target), encode(peer.batch(seq, incarnation, actor_id=target)))
        sent = time.monotonic()
        self.spoofed += SPOOF_PUTS

        def counted() -> int | None:
            seen = self.observer.latest(self.learner_id, sent)
            rise = int(seen[1].get("rejected", 0)) - before if seen else 0
            return rise if rise >= SPOOF_PUTS else None

        rise = self._wait("the learner to count the lies", RECOVERY_TIMEOUT_S, counted)
        figures = {"peer": ident, "claimed": target, "lies_on_own_key": SPOOF_PUTS, "puts_on_claimed_key": on_target}
        return True, {**figures, "learner_rejected_rise": rise, "recovered_s": since(sent)}

    def _unauthenticated(self) -> tuple[bool, dict[str, Any]]:
        conf = self.wiring.client_dict(MALLORY)
        del conf["transport"]["auth"]  # a valid certificate, no password
        return self._refused(conf)

    def _wrong_certificate(self) -> tuple[bool, dict[str, Any]]:
        with tempfile.TemporaryDirectory(prefix="chaos-other-ca-") as other:
            assert self.wiring.secure is not None
            foreign = dataclasses.replace(self.wiring.secure, folder=Path(other), actor_ids=(MALLORY,))
            write_secure_set(foreign)  # another CA, and a mallory certificate signed by it
            conf = self.wiring.client_dict(MALLORY)  # the genuine password: only the certificate is wrong
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
        control = opens(self.wiring.client_dict(MALLORY))
        conf["connect"]["timeout_ms"] = REFUSAL_TIMEOUT_MS
        started = time.monotonic()
        try:
            with Peer(zenoh.Config.from_json5(json.dumps(conf)), self.keys, MALLORY, self.formulation) as peer:
                peer.put(peer.own_key, encode(peer.batch(0, secrets.randbits(64), n=INTRUDER_TUPLES)))
                time.sleep(STATUS_SETTLE_S)
        except zenoh.ZError as exc:
            error = str(exc).split(" at ")[0]  # zenoh appends the Rust source location
            return control, {"refused": True, "control_opened": control, "error": error, "refused_s": since(started)}
        log.warning("a session that should have been refused opened; it put %d tuples as mallory", INTRUDER_TUPLES)
        return control, {"refused": False, "control_opened": control}

    def _oversize(self) -> tuple[bool, dict[str, Any]]:
        ident = self.wiring.hostile("oversizer")
        watched = (ROUTER, self.learner_id)
        before = self.rss.measure(watched)
        with Peer(self.wiring.session(ident), self.keys, ident, self.formulation) as peer:
            peer.await_learner()
            peak, put_s = self._peak_rss_while(watched, lambda: peer.put(peer.own_key, bytes(OVERSIZE_BYTES)))
        after = time.monotonic()
        arrived, _ = self._wait(
            "a learner status after the oversize put", RECOVERY_TIMEOUT_S, lambda: self._learner_since(after)
        )
        rise = {name: round(peak.get(name, 0.0) - before.get(name, 0.0), 1) for name in watched}
        up = self.learner_id in self.children.running()
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
        started, peak = time.monotonic(), self.rss.measure(names)
        worker.start()
        ended: float | None = None
        while ended is None or time.monotonic() - ended < OVERSIZE_SETTLE_S:
            time.sleep(0.25)
            for name, mb in self.rss.measure(names).items():
                peak[name] = max(peak.get(name, 0.0), mb)
            if ended is None and not worker.is_alive():
                ended = time.monotonic()
            if ended is None and time.monotonic() - started > RECOVERY_TIMEOUT_S:
                raise WaitTimeout(f"the {OVERSIZE_BYTES} B put still blocked after {RECOVERY_TIMEOUT_S:.0f} s")
        if errors:
            raise errors[0]
        return peak, round(ended - started, 1)

    # -- the end ----------------------------------------------------------------------------------------------------

    def _drain(self) -> tuple[dict[str, dict[str, Any] | None], dict[str, Any]]:
        """Stop the actors (each flushes its outbox and prints its final status), then the learner (it writes its
        report), then the router; the actors' final statuses, and how every process ended."""
        running = self.children.running()
        ended: dict[str, Any] = {
            name: {"running": name in running} for name in (ROUTER, self.learner_id, *self.actor_ids)
        }
        for actor in self.actor_ids:
            self.children.signal(actor, signal.SIGTERM)
        finals: dict[str, dict[str, Any] | None] = {}
        for actor in self.actor_ids:
            ended[actor]["code"] = self.children.wait(actor, self.actors[0].flush_timeout + ACTOR_STOP_MARGIN_S)
            finals[actor] = last_json(self.children.stdout(actor))
        for name, grace in ((self.learner_id, LEARNER_STOP_S), (ROUTER, 10.0)):
            self.children.signal(name, signal.SIGTERM)
            ended[name]["code"] = self.children.wait(name, grace)
        return finals, ended

    def _results(self, finals: dict[str, dict[str, Any] | None], ended: dict[str, Any]) -> dict[str, Any]:
        report_path = self.run_dir / "report.json"
        report = json.loads(report_path.read_text()) if report_path.exists() else None
        evidence = Evidence(
            actor_ids=self.actor_ids,
            report=report,
            finals=finals,
            killed=self.killed,
            versions=self.observer.versions(),
            restarts=self.restarts,
            poison_id=self.wiring.hostile("poisoner"),
            spoofed=self.spoofed,
            records=self.records,
            requested=self.options.faults,
            rss_samples=self.rss.samples,
            rss_baseline=self.rss.baseline,
            ended=ended,
        )
        return figures_and_checks(evidence, self._summary())

    def _summary(self) -> dict[str, Any]:
        return {
            "run_id": self.run_id,
            "run_dir": str(self.run_dir),
            "secure": self.options.secure,
            "namespace": self.keys.namespace,
            "endpoint": self.wiring.endpoint,
            "actors": len(self.actor_ids),
            "duration_s": self.options.duration,
            "fault_interval_s": self.options.fault_interval,
            "wall_s": self._t(),
            "rss_interval_s": self.options.rss_interval,
        }
