"""One chaos run (:class:`Chaos`): the cluster started with :mod:`tools.cluster`'s pieces, the faults of
:mod:`~tools.chaos.faults` applied in rotation, then the drain and the figures with the checks."""

from __future__ import annotations

import itertools
import json
import logging
import signal
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import zenoh

from learner.checkpoint import CHECKPOINT
from protocol import KeySpace
from protocol.security import OBSERVER, ROUTER
from tools.chaos.checks import Evidence, figures_and_checks
from tools.chaos.faults import Faults, Scene
from tools.chaos.network import Network, NetworkError
from tools.chaos.observe import (
    MALLORY,
    RECOVERY_TIMEOUT_S,
    Observer,
    RssSampler,
    WaitTimeout,
    last_json,
    listening,
    wait_for,
)
from tools.chaos.options import NETWORK_FAULTS, ChaosOptions
from tools.chaos.proxy import Proxies
from tools.cluster import (
    ACTOR_NICENESS,
    Children,
    UpConfig,
    child_configs,
    ennc_ql_argv,
    make_endpoints,
    write_configs,
)

log = logging.getLogger("tools.chaos")  # one name for the package: its lines read "tools.chaos: ..."

FIRST_POLICY_TIMEOUT_S = 900.0
"""Phase 1 with the default budget takes minutes on a busy two-core machine."""
ACTOR_STOP_MARGIN_S = 60.0
"""An actor stops after its current trial and its outbox flush (``--actor-flush-timeout``) plus this."""
LEARNER_STOP_S = 600.0
"""The learner's final evaluation (``--learner-final-eval-trials``) and report may take minutes."""

T = TypeVar("T")


class Chaos:
    """One chaos run: the cluster, the faults in rotation, the drain, the figures. Usage::

    out = Chaos(options, config, run_dir, run_id, namespace).run()   # the JSON object ``--json`` prints
    """

    def __init__(
        self,
        options: ChaosOptions,
        config: UpConfig,
        run_dir: Path,
        run_id: str,
        namespace: str,
        skipped: dict[str, str] | None = None,
    ) -> None:
        self.options = options
        self.skipped = skipped or {}
        """Faults asked for but not applied, with why."""
        self.run_dir = run_dir
        self.run_id = run_id
        self.keys = KeySpace(namespace)
        self.learner, self.actors = child_configs(config)
        self.learner_id = self.learner.learner_id
        self.actor_ids = [a.actor_id for a in self.actors]
        self.formulation = self.learner.resolved
        # With network faults every process is a host of its own, the clients reaching the router through chaos's
        # link proxies on the router's host; the router's certificate then names its address there too.
        self.network = (
            Network([ROUTER, self.learner_id, *self.actor_ids]) if NETWORK_FAULTS & set(options.faults) else None
        )
        self.proxies: Proxies | None = None
        self.links: dict[str, int] = {}
        """Each client's link: the port of its proxy on the router's host."""
        # Every process a client of a router chaos can restart; chaos plays mallory itself in a secure run.
        self.endpoints = make_endpoints(
            run_dir,
            namespace,
            self.learner_id,
            self.actor_ids,
            router=True,
            secure=options.secure,
            others=(MALLORY,),
            hosts=(self.network.address[ROUTER],) if self.network else (),
        )
        self.no_shared_memory = run_dir / "no-shared-memory.json5"
        if self.network is not None and not options.secure:  # the secure configurations have it off already
            # The hosts share /dev/shm: with shared memory on, payloads would bypass the links the faults act on.
            self.no_shared_memory.write_text(json.dumps({"transport": {"shared_memory": {"enabled": False}}}) + "\n")
        self.lease_s = int(self.endpoints.session(OBSERVER).get_json("transport/link/tx/lease")) / 1000
        self.t0 = time.monotonic()
        # Killed at once on the way out, whatever happened: the drain has stopped them gently if all went well.
        self.children = Children(run_dir, keep_stdout=True, grace=0.0)
        self.observer = Observer()
        self.rss = RssSampler(self.children, options.rss_interval, self.t0)
        self.records: list[dict[str, Any]] = []
        self.faults = Faults(
            Scene(
                run_dir=run_dir,
                learner_id=self.learner_id,
                actor_ids=self.actor_ids,
                formulation=self.formulation,
                keys=self.keys,
                secure=options.secure,
                lease_s=self.lease_s,
                children=self.children,
                endpoints=self.endpoints,
                observer=self.observer,
                rss=self.rss,
                network=self.network,
            ),
            self,
        )
        write_configs(config, self.learner, self.actors, run_dir)

    def run(self) -> dict[str, Any]:
        """Start the cluster, apply the faults, drain it and return the figures with the checks; every child is
        killed on the way out, whatever happened (an exception, Ctrl-C)."""
        with self._hosts():
            try:
                self.children.start(ROUTER, self.router_argv())
                # The observer's zenoh.open would wait for the router forever (clients retry it without end).
                self.wait("the router to listen", RECOVERY_TIMEOUT_S, lambda: listening(self.endpoints.port))
                with self.observer.watching(self.endpoints.session(OBSERVER), self.keys):
                    self.children.start(self.learner_id, self.learner_argv(resume=False))
                    for actor in self.actor_ids:
                        self.children.start(actor, self.actor_argv(actor), nice=ACTOR_NICENESS)
                    self.rss.start()
                    try:
                        self._rotate_faults()
                    finally:
                        self.rss.stop()
                    finals, codes = self._drain()
            finally:
                self.children.close()
            relayed = self.proxies.relayed() if self.proxies else None
        return self._results(finals, codes, relayed)

    @contextmanager
    def _hosts(self) -> Iterator[None]:
        """With network faults: the namespaces, chaos's thread on the router's host (its sessions and proxies
        there) and a proxy per client; all of it gone on the way out. Without: nothing to do."""
        if self.network is None:
            yield
            return
        with self.network.built():
            self.network.enter(ROUTER)
            self.proxies = Proxies(("127.0.0.1", self.endpoints.port)).start()
            try:
                for client in (self.learner_id, *self.actor_ids):
                    self.links[client] = self.proxies.add(client, self.network.address[ROUTER])
                yield
            finally:
                self.proxies.close()

    def router_argv(self) -> list[str]:
        flags = self.endpoints.router_flags()
        if self.network is None:
            return ennc_ql_argv("router", *flags)
        shared_memory_off = [] if self.options.secure else ["--zenoh-config", str(self.no_shared_memory)]
        return self.network.on(ROUTER, ennc_ql_argv("router", *shared_memory_off, *flags))

    def learner_argv(self, resume: bool) -> list[str]:
        argv = ["learner", "--config", str(self.run_dir / "learner.toml"), "--run-dir", str(self.run_dir), "--json"]
        return self._on(self.learner_id, [*argv, *(["--resume"] if resume else [])])

    def actor_argv(self, actor: str) -> list[str]:
        return self._on(actor, ["actor", "--config", str(self.run_dir / f"{actor}.toml"), "--json"])

    def restart(self, ident: str) -> None:
        """Start ``ident`` again after a fault killed it, as the run started it; the learner resumes."""
        if ident == ROUTER:
            self.children.start(ROUTER, self.router_argv())
        elif ident == self.learner_id:
            self.children.start(ident, self.learner_argv(resume=True))
        else:
            self.children.start(ident, self.actor_argv(ident), nice=ACTOR_NICENESS)

    def _on(self, ident: str, argv: list[str]) -> list[str]:
        """A learner's or actor's command line with its zenoh flags, on its own host when there are hosts."""
        flags = self.endpoints.flags(ident)
        if self.network is None:
            return ennc_ql_argv(*argv, *flags)
        link = f"{self.network.address[ROUTER]}:{self.links[ident]}"
        if self.options.secure:  # the flag overrides the configuration's endpoint
            flags = [*flags, "--connect", f"tls/{link}"]
        else:
            flags = ["--zenoh-config", str(self.no_shared_memory)] + [
                f"tcp/{link}" if flag == self.endpoints.endpoint else flag for flag in flags
            ]
        return self.network.on(ident, ennc_ql_argv(*argv, *flags))

    def checkpoint_mtime(self) -> int:
        path = self.run_dir / CHECKPOINT
        return path.stat().st_mtime_ns if path.exists() else 0

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
            self.wait("a first policy", FIRST_POLICY_TIMEOUT_S, lambda: self.observer.versions())
            broadcast = time.time_ns()
            self.wait("a checkpoint of it", RECOVERY_TIMEOUT_S, lambda: self.checkpoint_mtime() > broadcast)
        except WaitTimeout as exc:
            log.error("no fault applied: %s; the learner's log ends:\n%s", exc, self.children.tail(self.learner_id))
            return False
        log.info("first policy v%d checkpointed at t=%.0fs: faults begin", self.observer.versions()[0], self._t())
        return True

    def _t(self) -> float:
        return round(time.monotonic() - self.t0, 1)

    def wait(self, what: str, timeout: float, probe: Callable[[], T | None]) -> T:
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
            ok, figures = self.faults.apply[name]()
        except (WaitTimeout, NetworkError, zenoh.ZError) as exc:
            ok, figures = False, {"error": str(exc)}
        record = {"name": name, "t_s": t, "ok": ok, **figures}
        (log.info if ok else log.error)("fault %s %s: %s", name, "held" if ok else "FAILED", json.dumps(figures))
        return record

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

    def _results(
        self,
        finals: dict[str, dict[str, Any] | None],
        ended: dict[str, Any],
        relayed: dict[str, dict[str, int]] | None,
    ) -> dict[str, Any]:
        report_path = self.run_dir / "report.json"
        report = json.loads(report_path.read_text()) if report_path.exists() else None
        evidence = Evidence(
            actor_ids=self.actor_ids,
            report=report,
            finals=finals,
            killed=self.faults.killed,
            versions=self.observer.versions(),
            restarts=self.faults.restarts,
            poison_id=self.faults.hostile("poisoner"),
            spoofed=self.faults.spoofed,
            records=self.records,
            requested=self.options.faults,
            rss_samples=self.rss.samples,
            rss_baseline=self.rss.baseline,
            ended=ended,
            learner_id=self.learner_id,
            relayed=relayed,
        )
        return figures_and_checks(evidence, self._summary())

    def _summary(self) -> dict[str, Any]:
        return {
            "run_id": self.run_id,
            "run_dir": str(self.run_dir),
            "secure": self.options.secure,
            "namespace": self.keys.namespace,
            "endpoint": self.endpoints.endpoint,
            "actors": len(self.actor_ids),
            "duration_s": self.options.duration,
            "fault_interval_s": self.options.fault_interval,
            "wall_s": self._t(),
            "rss_interval_s": self.options.rss_interval,
            "skipped": self.skipped,
            "hosts": self.network.address if self.network else None,
        }
