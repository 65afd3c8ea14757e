"""The robot actor process: a simulator slice that streams experience to the learner and learns per-robot tables.

Call sequence (``run_actor`` wires it to a Zenoh transport; tests use an in-memory one)::

    actor = RobotActor(transport, ActorConfig(actor_id="actor-0", learn=(0, 1, 2, 3, 4)))
    actor.start()                 # liveliness token, subscriptions, ask the learner for its current policy
    stats = actor.run(stop)       # learning trials until stop / duration; returns counters
    actor.close()

Before the first policy arrives every robot explores randomly; afterwards the robots it learns act ε-greedily on
their own tables (phase 2, option 2) and the others follow the broadcast policy greedily. Experience goes out in
columnar batches stamped with the policy version, each with (incarnation, seq). Q-table increments carry the change
of each learned table since the previous increment, so none is lost when a broadcast overtakes it. Unacknowledged
messages stay in a bounded outbox and are re-sent when the learner comes back or an ack is overdue; a full outbox
slows the actor down instead of dropping anything.
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
import zlib
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from algorithm.agent import Phase2Config, TabularAgent
from algorithm.discretization import Discretization
from algorithm.policy import Policy
from algorithm.transitions import Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from monitor import Monitor, paths
from protocol import Ack, ExperienceBatch, Message, PolicyUpdate, QTableIncrement, Status, Transport
from sim import FEATURIZERS, ScenarioConfig, scenario
from sim.world import Observation, WorldState

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ActorConfig:
    actor_id: str
    scenario: str = "cmommt-v1"
    featurizer: str = "collab6d"
    learn: tuple[int, ...] | None = None
    """Robot ids whose tables this actor learns (and whose tuples it streams); None = every robot."""
    arenas: int = 256
    """Arenas simulated side by side; every arena holds all m robots."""
    seed: int = 0
    """Run seed; the actor's random stream is derived from (seed, actor id), so no two actors share one."""
    batch_size: int = 16384
    """Tuples per experience message."""
    outbox_limit: int = 256
    """Unacknowledged messages kept for re-sending; when full the actor waits for acks."""
    resend_after: float = 10.0
    """Seconds without an ack after which a message is sent again."""
    flush_timeout: float = 10.0
    """On stopping, seconds to wait for the learner to acknowledge the outbox (it acks after each checkpoint)."""
    duration: float | None = None
    """Stop after this many seconds (None: run until stopped)."""
    status_interval: float = 2.0
    phase2: Phase2Config = field(default_factory=Phase2Config)
    draw_every: int = 10
    """With monitoring on, every this many trials arena 0 is drawn at each step of the trial."""


@dataclass(slots=True)
class _Pending:
    key: str
    msg: Message
    sent_at: float


def parse_robots(text: str) -> tuple[int, ...]:
    """'0-4,7' -> (0, 1, 2, 3, 4, 7)."""
    robots: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, _, hi = part.partition("-")
        first, last = int(lo), int(hi or lo)
        if first < 0 or last < first:
            raise ValueError(f"bad robot range {part!r}")
        robots.extend(range(first, last + 1))
    if not robots:
        raise ValueError("no robots given")
    return tuple(sorted(set(robots)))


def policy_from_update(update: PolicyUpdate, n_robots: int, action_steps: int) -> Policy:
    """The acting policy of a broadcast: robot i uses row i (robots missing from the update use the mean row)."""
    disc = Discretization(
        prototypes=np.array(update.prototypes),
        labels=np.array(update.labels),
        offsets=np.array(update.offsets),
        scale=np.array(update.scale),
    )
    tables = np.tile(np.asarray(update.q_tables, np.float32).mean(axis=0), (n_robots, 1))
    visits = np.zeros((n_robots, disc.size), np.uint64)
    for row, robot in enumerate(np.asarray(update.robots)):
        if robot < n_robots:
            tables[robot] = update.q_tables[row]
            visits[robot] = update.visits[row]
    return Policy(
        featurizer=update.featurizer,
        discretization=disc,
        tables=tables,
        robot_table=np.arange(n_robots),
        action_steps=action_steps,
        visits=visits,
        version=int(update.version),
    )


class RobotActor:
    def __init__(self, transport: Transport, config: ActorConfig, monitor: Monitor | None = None) -> None:
        if config.featurizer not in FEATURIZERS:
            raise ValueError(f"unknown featurizer {config.featurizer!r}")
        self.transport = transport
        self.config = config
        self.monitor = monitor or Monitor()
        self.keys = transport.keys
        self.cfg = scenario(config.scenario)
        learn = config.learn if config.learn is not None else tuple(range(self.cfg.n_robots))
        if max(learn) >= self.cfg.n_robots:
            raise ValueError(f"robot {max(learn)} does not exist: the scenario has {self.cfg.n_robots} robots")
        self.learn = learn
        self.incarnation = secrets.randbits(63)
        seed = np.random.SeedSequence([config.seed, zlib.crc32(config.actor_id.encode())])
        self.slice = ExperienceSlice(
            self.cfg, SliceConfig(n_arenas=config.arenas, featurizer=config.featurizer, learners=learn), seed
        )
        self.lock = threading.Condition()
        self.outbox: OrderedDict[int, _Pending] = OrderedDict()
        self.seq = 0
        self.acked = -1
        self.resend_all = False
        self.pending_policy: PolicyUpdate | None = None
        self.agent: TabularAgent | None = None
        self.version = 0
        self.sent_visits = np.zeros(0, np.uint64)
        self.sent_tables = np.zeros(0)
        """Tables and visits as last handed in: an increment carries the change since then."""
        self.counters: dict[str, float] = {
            "tuples_sent": 0,
            "batches_sent": 0,
            "increments_sent": 0,
            "resent": 0,
            "trials": 0,
            "policies_applied": 0,
            "outbox_waits": 0,
        }
        self._handles: list[Any] = []

    # -- wiring -------------------------------------------------------------------------------------------------

    def start(self) -> None:
        t, keys, me = self.transport, self.keys, self.config.actor_id
        self._handles.append(t.liveliness_token(keys.alive("actor", me)))
        self._handles.append(t.subscribe(keys.policy(), PolicyUpdate, self._on_policy))
        self._handles.append(t.subscribe(keys.ack(me), Ack, self._on_ack))
        self._handles.append(t.liveliness_subscribe(keys.alive("learner"), self._on_learner_join, _noop))
        for update in t.get(keys.policy_latest(), PolicyUpdate):
            self._on_policy(update)
        log.info(
            "actor %s (incarnation %x): %d arenas, learning robots %s",
            me,
            self.incarnation,
            self.config.arenas,
            self.learn,
        )

    def close(self) -> None:
        for handle in reversed(self._handles):
            handle.close()
        self._handles.clear()

    def _on_policy(self, update: PolicyUpdate) -> None:
        with self.lock:
            if update.version > max(self.version, 0 if self.pending_policy is None else self.pending_policy.version):
                self.pending_policy = update

    def _on_ack(self, ack: Ack) -> None:
        if ack.incarnation != self.incarnation:
            return
        with self.lock:
            self.acked = max(self.acked, ack.seq)
            while self.outbox and next(iter(self.outbox)) <= ack.seq:
                self.outbox.popitem(last=False)
            self.lock.notify_all()

    def _on_learner_join(self, key: str) -> None:
        # A (re)started learner has not seen what it did not acknowledge: send the whole outbox again.
        with self.lock:
            if self.outbox:
                self.resend_all = True
                log.info("learner %s joined: re-sending %d unacknowledged messages", key, len(self.outbox))

    # -- the loop -----------------------------------------------------------------------------------------------

    def run(self, stop: threading.Event) -> dict[str, float]:
        start = time.monotonic()
        next_status = start
        while not stop.is_set():
            if self.config.duration is not None and time.monotonic() - start >= self.config.duration:
                break
            self._apply_policy()
            watch = self._watch_trial(start) if self.monitor.enabled else None
            batch = self.slice.run_trial(self.agent, learn=self.agent is not None, on_step=watch)
            self.counters["trials"] += 1
            if watch is not None:
                watch.report(batch, self.counters["tuples_sent"] + len(batch), self.version)
            self._send_experience(batch)
            if self.agent is not None:
                self._send_increments()
            self._service_outbox(stop)
            if time.monotonic() >= next_status:
                self._publish_status()
                next_status = time.monotonic() + self.config.status_interval
        self._flush(timeout=self.config.flush_timeout)
        self._publish_status()
        return dict(self.counters, outbox=len(self.outbox), policy_version=self.version)

    def _watch_trial(self, start: float) -> _TrialWatch:
        trial = int(self.counters["trials"])
        return _TrialWatch(
            self.monitor,
            self.cfg,
            self.config.actor_id,
            first_step=trial * self.cfg.learning_steps,
            draw=trial % self.config.draw_every == 0,
            start=start,
        )

    def _apply_policy(self) -> None:
        with self.lock:
            update, self.pending_policy = self.pending_policy, None
        if update is None or update.version <= self.version:
            return
        if self.agent is not None:
            self._send_increments()  # hand in what was learned on the old tables before adopting the new ones
        policy = policy_from_update(update, self.cfg.n_robots, self.cfg.action_steps)
        agent = TabularAgent(policy, self.config.phase2)
        if self.agent is not None and _same_cells(self.agent.discretization, policy.discretization):
            # The broadcast may not hold our newest increments yet (they are in flight): keep the learning we have
            # not handed in, on top of the merged tables. What was handed in comes back in a later broadcast.
            learned = list(self.learn)
            agent.tables[learned] += self.agent.tables[learned] - self.sent_tables[learned]
            agent.visits[learned] = self.agent.visits[learned]
            self.sent_tables[learned] = policy.tables[learned]
        else:
            self.sent_tables = agent.tables.copy()
            self.sent_visits = agent.visits.copy()
        self.agent = agent
        self.version = int(update.version)
        self.counters["policies_applied"] += 1
        log.debug("actor %s applied policy version %d", self.config.actor_id, self.version)

    def _next_seq(self) -> int:
        seq = self.seq
        self.seq += 1
        return seq

    def _send(self, key: str, msg: Message, seq: int) -> None:
        with self.lock:
            self.outbox[seq] = _Pending(key, msg, time.monotonic())
        self.transport.publish(key, msg)

    def _send_experience(self, batch: Transitions) -> None:
        key = self.keys.experience(self.config.actor_id)
        for start in range(0, len(batch), self.config.batch_size):
            part = batch.take(np.arange(start, min(start + self.config.batch_size, len(batch))))
            seq = self._next_seq()
            msg = ExperienceBatch(
                actor_id=self.config.actor_id,
                incarnation=self.incarnation,
                seq=seq,
                policy_version=self.version,
                robot=part.robot,
                state=part.state,
                action=part.action,
                reward=part.reward,
                next_state=part.next_state,
                done=part.done,
            )
            self._send(key, msg, seq)
            self.counters["tuples_sent"] += len(part)
            self.counters["batches_sent"] += 1

    def _send_increments(self) -> None:
        agent = self.agent
        assert agent is not None
        key = self.keys.qinc(self.config.actor_id)
        offsets = agent.discretization.offsets.astype(np.int64)
        for robot in self.learn:
            delta = agent.visits[robot] - self.sent_visits[robot]
            if not delta.any():
                continue
            change = agent.tables[robot] - self.sent_tables[robot]
            seq = self._next_seq()
            msg = QTableIncrement(
                actor_id=self.config.actor_id,
                incarnation=self.incarnation,
                seq=seq,
                policy_version=self.version,
                robot=robot,
                q=change.astype(np.float32),
                visits=np.minimum(delta, np.iinfo(np.uint32).max).astype(np.uint32),
                offsets=offsets,
            )
            self._send(key, msg, seq)
            self.sent_visits[robot] = agent.visits[robot]
            self.sent_tables[robot] = agent.tables[robot]
            self.counters["increments_sent"] += 1

    def _resend_due(self) -> None:
        """Re-send what is overdue, and everything after a learner (re)joined once its subscription is visible here:
        a message published before the new learner's subscriber reaches this session would be lost again."""
        now = time.monotonic()
        with self.lock:
            if self.resend_all and not self.transport.has_subscribers(self.keys.experience(self.config.actor_id)):
                return
            due = [
                (seq, p)
                for seq, p in self.outbox.items()
                if self.resend_all or now - p.sent_at >= self.config.resend_after
            ]
            self.resend_all = False
        for seq, pending in due:
            pending.sent_at = now
            self.transport.publish(pending.key, pending.msg)
            self.counters["resent"] += 1
            log.debug("re-sent seq %d", seq)

    def _service_outbox(self, stop: threading.Event) -> None:
        """Re-send what is due, and wait while the outbox is full (slowing down instead of dropping)."""
        while True:
            self._resend_due()
            with self.lock:
                if len(self.outbox) < self.config.outbox_limit or stop.is_set():
                    return
                self.counters["outbox_waits"] += 1
                self.lock.wait(timeout=1.0)

    def _flush(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self._resend_due()
            with self.lock:
                if not self.outbox:
                    break
                self.lock.wait(timeout=0.2)
        if self.outbox:
            log.warning("actor %s stops with %d unacknowledged messages", self.config.actor_id, len(self.outbox))

    def _publish_status(self) -> None:
        with self.lock:
            outbox = len(self.outbox)
            acked = self.acked
        counters = dict(self.counters, outbox=outbox, acked_seq=acked, policy_version=self.version)
        status = Status(
            sender=self.config.actor_id,
            role="actor",
            wall_time=time.time(),
            counters={k: float(v) for k, v in counters.items()},
        )
        self.transport.publish(self.keys.status(self.config.actor_id), status)


class _TrialWatch:
    """The step hook of one learning trial under monitoring: arena 0 drawn at each step of a sampled trial, and the
    trial's coverage over every arena; ``report`` logs the trial's figures on the actor's ``sim_step`` timeline."""

    def __init__(
        self, monitor: Monitor, cfg: ScenarioConfig, actor_id: str, first_step: int, draw: bool, start: float
    ) -> None:
        self.monitor = monitor
        self.cfg = cfg
        self.actor_id = actor_id
        self.origin = paths.actor_arena(actor_id)
        self.step = first_step
        self.draw = draw
        self.start = start
        self.steps = 0
        self.covered = 0.0

    def __call__(self, world: WorldState, obs: Observation) -> None:
        self.step += 1
        self.steps += 1
        self.covered += float(obs.covered.mean())
        if self.draw:
            self.monitor.arena(
                self.origin,
                world.robot_pos[0],
                world.target_pos[0],
                sensing_range=self.cfg.sensing_range,
                arena_radius=self.cfg.arena_radius,
                sim_step=self.step,
            )

    def report(self, batch: Transitions, tuples_sent: float, version: int) -> None:
        final = batch.reward[batch.done]
        self.monitor.actor_metrics(
            self.actor_id,
            sim_step=self.step,
            coverage=100.0 * self.covered / max(self.steps * self.cfg.n_targets, 1),
            mean_reward=float(final.mean()) if final.size else None,
            tuples_per_s=tuples_sent / max(time.monotonic() - self.start, 1e-9),
            policy_version=version,
        )


def _noop(_key: str) -> None:
    return None


def _same_cells(a: Discretization, b: Discretization) -> bool:
    return a.prototypes.shape == b.prototypes.shape and bool(np.array_equal(a.prototypes, b.prototypes))
