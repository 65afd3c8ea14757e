"""The central ENNC-QL learner: the loop that ties intake, fits, policy state, evaluation and checkpoints together.

Call sequence (``learner.wiring.connect`` holds every subscription; tests and serial mode use the in-memory
transport)::

    service = LearnerService(transport, LearnerConfig(), run_dir=Path("runs/x"), resume=False)
    with connect(service, transport):       # subscriptions, late-joiner queryable, liveliness (one ExitStack)
        report = service.run(stop)          # until stop / duration: fits, merges, broadcasts, evaluations, checkpoints

Experience is de-duplicated by (actor, incarnation, seq) into a bounded store (``learner.intake``, which also
rejects what it refuses for good); it is acknowledged only once a checkpoint holding it is on disk, so an actor's
outbox covers a learner crash. Phase 1 runs in the background when due (``learner.fitting``). The actors' Q-table
increments are merged cell by cell, weighted by the visits behind them, into the one set of tables the run keeps to
its end, and broadcast with a strictly increasing version (``learner.policy_state``). The loop only stores, merges,
broadcasts and publishes status: checkpoints and evaluations run on threads of their own, so neither a 44-MB
checkpoint nor seconds of test trials hold up a policy or a status. At the end the run saves its last policy by the
one rule of ``algorithm.selection.SaveRule`` and scores it on the reported test trials beside every reference.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import psutil

from algorithm.discretization import Discretization
from algorithm.files import write_atomic
from algorithm.phase1 import estimator
from algorithm.policy import Policy
from algorithm.policy_file import save_policy
from algorithm.selection import SavedPolicy, SaveRule, ScoringStopped
from learner.checkpoint import Checkpointer, CheckpointError, VersionMark
from learner.config import LearnerConfig
from learner.evaluator import EvaluationStopped, Evaluator
from learner.fitting import Fitter
from learner.intake import ExperienceIntake
from learner.membership import Membership
from learner.policy_state import PolicyState
from learner.report import LearnerReport, LearnerStatus
from monitor import Monitor
from monitor.learner import LearnerWatch
from protocol import Ack, QTableIncrement, Status, Transport
from sim import scenario

log = logging.getLogger(__name__)


class LearnerService:
    def __init__(
        self,
        transport: Transport,
        config: LearnerConfig,
        run_dir: Path,
        resume: bool = False,
        monitor: Monitor | None = None,
    ) -> None:
        self.transport = transport
        self.config = config
        self.run_dir = run_dir
        self.scenario = scenario(config.scenario)
        formulation = config.resolved
        self.intake = ExperienceIntake(config.store_capacity, formulation, transport)
        self.members = Membership()
        self.version_mark = VersionMark(run_dir)
        self.state = PolicyState(
            self.scenario.n_robots,
            formulation,
            self.scenario.name,
            self.scenario.action_steps,
            config.method,
            team=config.team_policy,
            on_version=self.version_mark.record,
        )
        self.fitter = Fitter(config, on_fitted=self._adopt)
        self.evaluator = Evaluator(self.scenario, config.eval_trials, config.eval_steps, config.final_eval_trials)
        self.rule = SaveRule(self.scenario, config.law_margin, config.margin_trials, config.eval_steps)
        self.saved: SavedPolicy | None = None
        """What the run saved and why, once it ended (the record its report prints)."""
        self._saved_policy: Policy | None = None
        self.checkpointer = Checkpointer(run_dir)
        # The viewer's train_time is the run clock of the learning curve.
        self.watch = LearnerWatch(monitor or Monitor(), self.scenario, clock=self.elapsed)
        # An increment enters the ledger and the pending merge together, and a checkpoint snapshots both together:
        # otherwise a checkpoint could acknowledge an increment it does not hold, or hold one it does not acknowledge.
        self._sequence_lock = threading.Lock()
        self._checkpoint_lock = threading.Lock()  # the checkpoint thread and a finished fit both checkpoint
        # The loop and a finished fit both broadcast: a version is numbered and sent under one lock, or the later
        # version could go on the wire first and the actors would see the versions go down.
        self._broadcast_lock = threading.Lock()
        self._elapsed_before = 0.0
        self._started = time.monotonic()
        self._ending = threading.Event()
        """Set once training stops: an evaluation under way gives up."""
        self._stopped_at: float | None = None
        self._scoring: float | None = None
        """The final evaluation's share done, once it started (the end's statuses carry it)."""
        """The run clock when training stopped: the wind-down (a fit finishing, the final evaluation) is no training,
        and a stopped run resumed must train for what was left when it stopped."""
        self.resumes: list[dict[str, Any]] = []
        """Every resume of this run (restored with the checkpoint, this one's added at its first broadcast)."""
        self._resumed = resume
        if resume:  # first: a bad checkpoint fails in a second, before the libraries load
            self._restore()
        estimator()  # torch and scikit-learn load now, not at the first fit while the actors wait for a policy

    # -- handlers (called by the transport's threads, see learner.wiring) -------------------------------------------

    def on_increment(self, msg: QTableIncrement) -> None:
        with self._sequence_lock:
            if self.intake.accept_sequence(msg.actor_id, msg.incarnation, msg.seq):
                self.state.add_increment(msg)

    def announce(self) -> None:
        """Broadcast the restored policy at once (if resumed), so actors need not wait for the next merge."""
        with self._broadcast_lock:
            current = self.state.current
            if current is not None:
                self.transport.publish(self.transport.keys.policy(), current)
        if self._resumed:
            now = time.time()
            self.resumes.append(
                {
                    "at_s": round(self._elapsed_before, 2),
                    "policy_version": self.state.version,
                    "wall_time": now,
                    # From the process's start (interpreter and imports included) to this first broadcast.
                    "startup_s": round(now - psutil.Process().create_time(), 2),
                }
            )
        log.info("learner %s started (policy version %d)", self.config.learner_id, self.state.version)

    # -- the loop ---------------------------------------------------------------------------------------------------

    def elapsed(self) -> float:
        """Seconds of training of the run, resumes included; frozen once training stops."""
        if self._stopped_at is not None:
            return self._stopped_at
        return self._elapsed_before + time.monotonic() - self._started

    def run(self, stop: threading.Event) -> LearnerReport:
        c = self.config
        self._started = time.monotonic()
        self.watch.started(c.resolved, self.evaluator.references)
        next_broadcast = next_status = self._started
        checkpoints = _Periodic("checkpoints", self.checkpoint, c.checkpoint_interval, at_once=True)
        evaluations = _Periodic("evaluations", self._evaluate, c.eval_interval, at_once=False)
        with checkpoints, evaluations:
            while not stop.is_set() and checkpoints.failure is None and evaluations.failure is None:
                if c.duration is not None and self.elapsed() >= c.duration:
                    break
                self.fitter.poll(self.intake, self.state.discretization)
                now = time.monotonic()
                if self.state.fitted and now >= next_broadcast:
                    self._broadcast()
                    next_broadcast = now + c.broadcast_interval
                if now >= next_status:
                    self._publish_status()
                    next_status = now + c.status_interval
                stop.wait(0.05)
            self._stopped_at = self.elapsed()
            self._ending.set()
        with self._heartbeat():
            return self._finish(stopped=stop.is_set(), urgent=getattr(stop, "urgent", None))

    @contextlib.contextmanager
    def _heartbeat(self) -> Iterator[None]:
        """A status every ``status_interval`` on a thread of its own while the end's work (the margin choice, the
        checkpoint, the scoring) holds the loop: a peer sees the learner alive, and the scoring's progress, throughout
        (one part of the scoring or the margin choice can take ten seconds and more)."""
        done = threading.Event()

        def beat() -> None:
            while not done.wait(self.config.status_interval):
                self._publish_status(self._scoring)

        thread = threading.Thread(target=beat, name="end-status", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()

    def _adopt(self, disc: Discretization) -> None:
        """A fit's new discretization (on the fit's thread): on disk before its first broadcast, so a resumed
        learner knows every discretization it ever published."""
        with self._checkpoint_lock:
            self.state.adopt(disc)
        self.checkpoint()
        self._broadcast()
        policy = self.state.policy()
        if policy is not None:
            self.watch.policy(policy)

    def _broadcast(self) -> None:
        with self._broadcast_lock:
            self.transport.publish(self.transport.keys.policy(), self.state.publish())

    def _evaluate(self) -> None:
        """A point of the learning curve: the policy the learner holds now (on the evaluations' thread)."""
        policy = self.state.policy()
        if policy is None:
            return
        try:
            coverage = self.evaluator.periodic(policy, at=self.elapsed(), stop=self._ending)
        except EvaluationStopped:
            return
        levels = self.evaluator.references()
        spread = {"learned": {"coverage": coverage, **self.evaluator.spread}}
        for name, figures in self.evaluator.reference_spread().items():
            spread[name] = {"coverage": levels[name], **figures}
        self.watch.evaluated(policy, coverage, spread, trials=self.config.eval_trials)
        log.info("evaluation of policy version %d: %.2f%% of targets observed", policy.version, coverage)

    def _publish_status(self, scoring: float | None = None) -> None:
        figures = self.intake.figures()
        fits, elapsed = self.fitter.fits, self.elapsed()
        status = LearnerStatus.of(figures, self.state, self.members, self.evaluator, fits, elapsed, scoring)
        me = self.config.learner_id
        msg = Status(sender=me, role="learner", wall_time=time.time(), counters=status.to_counters())
        self.transport.publish(self.transport.keys.status(me), msg)
        log.debug("status %s", status)
        self.watch.status(status, actors=self.members.seen(), lag=self.state.lag(figures.latest_version))

    # -- checkpoints, the end, the report ---------------------------------------------------------------------------

    def checkpoint(self) -> Path:
        """Write everything needed to resume, atomically, then acknowledge what it holds."""
        with self._checkpoint_lock:
            with self._sequence_lock:
                arrays, acks = self.intake.checkpoint_arrays()
                policy_arrays, policy_meta = self.state.to_arrays()
            meta = {
                **policy_meta,
                **self.fitter.to_meta(),
                **self.evaluator.to_meta(),
                **self.members.to_meta(),
                "elapsed": self.elapsed(),
                "resumes": self.resumes,
                "config": dataclasses.asdict(self.config),
            }
            path = self.checkpointer.save({**arrays, **policy_arrays}, meta)
        keys = self.transport.keys
        for actor, incarnation, seq in acks:
            self.transport.publish(keys.ack(actor), Ack(actor_id=actor, incarnation=incarnation, seq=seq))
        return path

    def _restore(self) -> None:
        arrays, meta = self.checkpointer.load()
        saved: dict[str, Any] = meta["config"] if isinstance(meta.get("config"), dict) else {}
        for name in ("formulation", "featurizer", "reward", "act_every"):
            theirs, mine = saved.get(name), getattr(self.config, name)
            if theirs is not None and theirs != mine:
                # Its tables and prototypes are of another state and action set: name both, not their dimensions.
                raise CheckpointError(
                    f"--resume: {self.checkpointer.path} holds a run of {name} {theirs}, and this learner's {name} "
                    f"is {mine}; resume it with --{name.replace('_', '-')} {theirs}, or start a new run in another "
                    "--run-dir"
                )
        try:
            self.intake.restore(arrays)
            self.state.restore(arrays, meta, published=self.version_mark.load())
            self.fitter.restore(meta)
            self.evaluator.restore(meta)
            self.members.restore(meta)
            self._elapsed_before = float(meta["elapsed"])
            self.resumes = list(meta["resumes"])
        except (KeyError, ValueError, TypeError, IndexError) as exc:
            # A readable file that is not a whole checkpoint of this learner: one line, not a traceback.
            raise CheckpointError(f"--resume: {self.checkpointer.path} is not a usable checkpoint: {exc!r}") from None
        log.info(
            "resumed from %s: %d tuples stored, policy version %d",
            self.checkpointer.path,
            len(self.intake),
            self.state.version,
        )

    def _finish(self, stopped: bool, urgent: threading.Event | None = None) -> LearnerReport:
        """The end: a fit under way finishes (its work is in the last policy), the last policy is saved by the rule
        and scored on the reported trials, with a status after each part of the scoring (its progress). A run stopped
        by a signal gives the margin choice up (the wind-down must fit a SIGTERM's grace) and saves the same tables
        by the rule's fallback; stopped again (``urgent``), it skips the scoring too and reports the policy
        unscored."""
        self.fitter.join()
        policy = None
        if self.state.fitted:
            self._broadcast()  # the increments still pending merged: the last policy holds them
            last = self.state.policy()
            assert last is not None
            try:
                if stopped:
                    raise ScoringStopped
                policy, self.saved = self.rule.decide(last, self.elapsed())
            except ScoringStopped:
                policy, self.saved = self.rule.fallback(last, self.elapsed())
            self._saved_policy = policy
            log.info("saving policy version %d: %s", policy.version, self.saved.reason)
        checkpoint = self.checkpoint()  # first: whatever the scoring meets, every acknowledged tuple is kept
        final = None if policy is None else self._score(policy, urgent)
        report = self._report(final, checkpoint, self.elapsed())
        write_atomic(self.run_dir / "report.json", json.dumps(report.to_dict(), indent=2).encode())
        return report

    def _score(self, policy: Policy, urgent: threading.Event | None) -> float | None:
        """The saved policy's final figure, with a status after each part of the scoring; None once ``urgent`` is
        set (stopped again)."""
        self._scoring = 0.0
        self._publish_status(self._scoring)

        def progress(done: int, total: int) -> None:
            self._scoring = done / total
            self._publish_status(self._scoring)

        try:
            final = self.evaluator.final(policy, progress, urgent)
        except EvaluationStopped:
            log.warning("stopped again: the final evaluation skipped, the policy is saved unscored")
            return None
        self.watch.final(policy, final, self.config.final_eval_trials, self.evaluator.comparison())
        log.info("final policy version %d: %.2f%% of targets observed", policy.version, final)
        return final

    def saved_report(self) -> LearnerReport:
        """The report of what a resumed learner's checkpoint holds, with its policy file (the last tables by the
        rule's fallback), without training or scoring: for a launcher whose learner was killed before it wrote its
        own report (``report.json`` is left to the launcher)."""
        last = self.state.policy()
        if last is not None:
            self._saved_policy, self.saved = self.rule.fallback(last, self._elapsed_before)
        return self._report(None, self.checkpointer.path, self._elapsed_before)

    def _report(self, final: float | None, checkpoint: Path, elapsed: float) -> LearnerReport:
        policy = self._saved_policy
        policy_file = None if policy is None else save_policy(policy, self.scenario, self.run_dir / "policy.npz")
        figures = self.intake.figures()
        status = LearnerStatus.of(figures, self.state, self.members, self.evaluator, self.fitter.fits, elapsed)
        return LearnerReport.of(
            self.config,
            status,
            figures,
            self.state,
            self.members,
            self.evaluator,
            final,
            policy_file,
            checkpoint,
            resumes=self.resumes,
            saved=self.saved,
        )


class _Periodic:
    """``work`` every ``interval`` seconds on a thread of its own (the first at once with ``at_once``). Checkpoints
    run so because acknowledgements follow them, and an evaluation (seconds of trials) must not hold them up:
    meanwhile every actor's outbox would fill with unacknowledged experience (≈ 40 MB a second each); evaluations run
    so because the loop's policies and status must go out at their intervals throughout. Work that fails ends the
    thread and is raised on the loop's thread when the block ends; ``failure`` tells the loop to stop."""

    def __init__(self, name: str, work: Callable[[], object], interval: float, at_once: bool) -> None:
        self._work = work
        self._interval = interval
        self._at_once = at_once
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self.failure: Exception | None = None

    def __enter__(self) -> _Periodic:
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self._done.set()
        self._thread.join()
        if self.failure is not None and exc_type is None:
            raise self.failure

    def _loop(self) -> None:
        try:
            if not self._at_once and self._done.wait(self._interval):
                return
            while True:
                self._work()
                if self._done.wait(self._interval):
                    return
        except Exception as exc:  # raised again on the loop's thread by __exit__
            self.failure = exc
