"""The robot actor: a simulator slice that streams experience to the learner and learns per-robot tables.

Call sequence (``actors.wiring.connect`` holds every subscription; tests and serial mode use the in-memory
transport)::

    actor = RobotActor(transport, ActorConfig(actor_id="actor-0", learn=(0, 1, 2, 3, 4)))
    with connect(actor, transport):       # liveliness token, subscriptions, the learner's current policy
        status = actor.run(stop)          # learning trials until stop / duration; flushes the outbox

Before the first policy arrives every robot explores randomly; afterwards the robots it learns act ε-greedily on
their own tables (phase 2, option 2) and the others follow the broadcast policy greedily. Experience goes out in
columnar batches of at most ``batch_size`` tuples; Q-table increments carry the change of each learned table since
the previous increment. The outbox gives each message its header (actor id, incarnation, the stream's next seq, the
policy version it was made under), keeps it until acknowledged and re-sends it when the learner comes back or an ack
is overdue; a full outbox slows the actor down instead of dropping.
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
import zlib
from dataclasses import dataclass
from functools import partial

import numpy as np

from actors.config import ActorConfig
from actors.increments import IncrementTracker
from actors.memory import release_compiler_code
from actors.outbox import Outbox
from actors.policy_client import PolicyClient
from algorithm.agent import TabularAgent
from algorithm.transitions import Batcher, Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from algorithm.wire import experience_batches, increment_message, status_counters
from monitor import Monitor
from monitor.trial import TrialWatch
from protocol import ExperienceBatch, Message, QTableIncrement, Status, Transport
from sim import scenario

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ActorStatus:
    """The actor's figures: published as a ``Status`` message's counters and returned by ``run``."""

    tuples_sent: int = 0
    batches_sent: int = 0
    increments_sent: int = 0
    resent: int = 0
    """Messages published again (overdue, or after a learner re-joined)."""
    trials: int = 0
    """Learning trials run (each in every arena)."""
    policies_applied: int = 0
    policies_refused: int = 0
    """Broadcasts over another formulation than this actor's (a misconfigured run), ignored."""
    outbox_waits: int = 0
    """Times the actor waited for acks because its outbox was full."""
    outbox: int = 0
    """Unacknowledged messages now."""
    tuples_acked: int = 0
    """Tuples the learner acknowledged (stored and checkpointed)."""
    visits_acked: int = 0
    """Q-learning visits in the acknowledged table increments: the learner's tables hold every one of them."""
    rejected: int = 0
    """Messages the learner rejected for good (dropped from the outbox)."""
    invalid: int = 0
    """Messages that failed their own validation and were dropped before the wire (a bug of this actor)."""
    acked_seq: int = -1
    """Cumulative acknowledgement (-1: none yet)."""
    policy_version: int = 0

    def to_counters(self) -> dict[str, float]:
        return status_counters(self)


class RobotActor:
    def __init__(self, transport: Transport, config: ActorConfig, monitor: Monitor | None = None) -> None:
        self.transport = transport
        self.keys = transport.keys
        self.config = config
        self.monitor = monitor or Monitor()
        steps = {} if config.learning_steps is None else {"learning_steps": config.learning_steps}
        self.scenario = scenario(config.scenario, **steps)
        self.learning_robots = config.learning_robots()
        self.incarnation = secrets.randbits(63)
        seed = np.random.SeedSequence([config.seed, zlib.crc32(config.actor_id.encode())])
        self.slice = ExperienceSlice(
            self.scenario,
            SliceConfig(
                config.resolved,
                n_arenas=config.arenas,
                learning_robots=self.learning_robots,
            ),
            seed,
        )
        self.outbox = Outbox(
            transport,
            config.actor_id,
            self.incarnation,
            config.outbox_limit,
            config.resend_after,
            probe_key=self.keys.experience(config.actor_id),
            stopping=self._stopping,
            on_acked=self._count_acked,
        )
        self.tracker = IncrementTracker(self.learning_robots)
        self.policy = PolicyClient(self.scenario.n_robots, config.phase2, self.tracker, config.resolved)
        self.agent: TabularAgent | None = None
        self._tuples = self._batches = self._increments = self._trials = 0
        self._tuples_acked = self._visits_acked = 0
        self._stop = threading.Event()  # run's stop event and the end of its duration: see _stopping
        self._deadline: float | None = None

    def _count_acked(self, msg: Message) -> None:
        if isinstance(msg, ExperienceBatch):
            self._tuples_acked += len(msg.reward)
        elif isinstance(msg, QTableIncrement):
            self._visits_acked += int(np.asarray(msg.visits, np.int64).sum())

    def status(self) -> ActorStatus:
        return ActorStatus(
            tuples_sent=self._tuples,
            batches_sent=self._batches,
            increments_sent=self._increments,
            resent=self.outbox.resent,
            trials=self._trials,
            policies_applied=self.policy.adopted,
            policies_refused=self.policy.refused,
            outbox_waits=self.outbox.waits,
            outbox=len(self.outbox),
            tuples_acked=self._tuples_acked,
            visits_acked=self._visits_acked,
            rejected=self.outbox.rejected,
            invalid=self.outbox.invalid,
            acked_seq=self.outbox.acked,
            policy_version=self.policy.version,
        )

    def run(self, stop: threading.Event, urgent: threading.Event | None = None) -> ActorStatus:
        """Learning trials until ``stop`` is set or the duration ends, then the outbox's flush, which ``urgent`` (a
        second Ctrl-C) cuts short."""
        self._stop = stop
        start = time.monotonic()
        # The viewer's train_time: seconds since this loop began, as the learner's clock counts from its own loop.
        self.monitor.use_clock(lambda: time.monotonic() - start)
        self._deadline = None if self.config.duration is None else start + self.config.duration
        next_status = start
        log.info(
            "actor %s (incarnation %x): %d arenas, learning robots %s",
            self.config.actor_id,
            self.incarnation,
            self.config.arenas,
            self.learning_robots,
        )
        while not self._stopping():
            self._adopt_policy()
            watch = self._watch_trial(start) if self.monitor.enabled else None
            finals = self._run_trial(watch)
            self._trials += 1
            # What this trial compiled (the first trial of each phase compiles its kernels) leaves LLVM's code resident
            # though it will not run again; releasing costs ~4 µs a trial (~0.25 s at 500 arenas).
            release_compiler_code()
            if watch is not None:
                watch.report(finals, self._tuples, self.policy.version)
            if self.agent is not None:
                self._send_increments(self.agent)
            if time.monotonic() >= next_status:
                self._publish_status()
                next_status = time.monotonic() + self.config.status_interval
            self._pace(start)
        left = self.outbox.flush(timeout=self.config.flush_timeout, cut=urgent)
        if left:
            log.warning("actor %s stops with %d unacknowledged messages", self.config.actor_id, left)
        self._publish_status()
        return self.status()

    def _pace(self, start: float) -> None:
        """With ``max_tuples_per_s``, rest until the tuples sent so far are within the rate (a stop or the
        duration's end cuts the rest short)."""
        rate = self.config.max_tuples_per_s
        if rate is None:
            return
        now = time.monotonic()
        rest = start + self._tuples / rate - now
        if self._deadline is not None:
            rest = min(rest, self._deadline - now)
        if rest > 0:
            self._stop.wait(rest)

    def _watch_trial(self, start: float) -> TrialWatch:
        return TrialWatch(
            self.monitor,
            self.scenario,
            self.config.actor_id,
            first_step=self._trials * self.scenario.learning_steps,
            draw=self._trials % self.config.draw_every == 0,
            start=start,
        )

    def _adopt_policy(self) -> None:
        update = self.policy.take()
        if update is None:
            return
        if self.agent is not None:
            self._send_increments(self.agent)  # hand in what was learned on the old tables, stamped with their version
        self.agent = self.policy.adopt(update, self.agent)

    def _stopping(self) -> bool:
        """The run's stop event is set or its duration is over: the loop ends, and a full outbox stops waiting."""
        return self._stop.is_set() or (self._deadline is not None and time.monotonic() >= self._deadline)

    def _run_trial(self, watch: TrialWatch | None) -> np.ndarray:
        """One learning trial, its tuples sent as each message fills (a trial's tuples are never held whole: 48 MB
        at 500 arenas); the rewards of its terminal tuples."""
        batcher = Batcher(self.config.batch_size, self._send_experience)
        finals: list[np.ndarray] = []

        def sink(part: Transitions) -> None:
            batcher.add(part)
            finals.append(part.reward[part.done])

        self.slice.stream_trial(sink, self.agent, update=self.agent is not None, on_step=watch)
        batcher.flush()
        return np.concatenate(finals) if finals else np.zeros(0, np.float32)

    def _send_experience(self, tuples: Transitions) -> None:
        key = self.keys.experience(self.config.actor_id)
        for build in experience_batches(tuples, self.config.batch_size, self.config.resolved):
            batch = self.outbox.add(key, build, policy_version=self.policy.version)
            if batch is not None:
                self._tuples += batch.n_tuples
                self._batches += 1

    def _send_increments(self, agent: TabularAgent) -> None:
        key = self.keys.qinc(self.config.actor_id)
        offsets = agent.discretization.offsets
        for robot, change, visits in self.tracker.take(agent):
            build = partial(increment_message, robot=robot, change=change, visits=visits, offsets=offsets)
            if self.outbox.add(key, build, policy_version=self.policy.version) is not None:
                self._increments += 1

    def _publish_status(self) -> None:
        status = Status(
            sender=self.config.actor_id,
            role="actor",
            wall_time=time.time(),
            counters=self.status().to_counters(),
        )
        self.transport.publish(self.keys.status(self.config.actor_id), status)
