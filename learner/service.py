"""The central ENNC-QL learner: the loop that ties intake, fits, policy state, evaluation and checkpoints together.

Call sequence (``learner.wiring.connect`` holds every subscription; tests and serial mode use the in-memory
transport)::

    service = LearnerService(transport, LearnerConfig(), run_dir=Path("runs/x"), resume=False)
    handles = connect(service, transport)   # subscriptions, late-joiner queryable, liveliness
    report = service.run(stop)              # until stop / duration: fits, merges, broadcasts, evaluations, checkpoints
    for h in reversed(handles): h.close()

Experience is de-duplicated by (actor, incarnation, seq) into a bounded store; it is acknowledged only once a
checkpoint holding it is on disk, so an actor's outbox covers a learner crash. Phase 1 runs when ``min_tuples``
are stored and again, warm-started, each time the tuples received have grown ``refit_growth`` times. The actors'
Q-table increments are merged cell by cell, weighted by the visits behind them, and the tables broadcast with a
strictly increasing version.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from pathlib import Path

import numpy as np

from algorithm.discretization import Discretization
from algorithm.phase1 import estimator, phase1
from algorithm.policy import Policy
from algorithm.policy_file import save_policy
from learner.checkpoint import Checkpointer, VersionMark
from learner.config import LearnerConfig
from learner.evaluator import TEST_SEED, Evaluator
from learner.intake import ExperienceIntake
from learner.policy_state import PolicyState
from learner.report import LearnerReport, LearnerStatus
from monitor import Monitor
from protocol import (
    N_ACTIONS,
    Ack,
    PolicyUpdate,
    ProtocolError,
    QTableIncrement,
    Reject,
    Status,
    Transport,
    peek_sequence,
)
from protocol.messages import MAX_NAME_LEN
from sim import HAND_MADE, evaluate, scenario

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
        self.keys = transport.keys
        self.config = config
        self.run_dir = run_dir
        self.monitor = monitor or Monitor()
        self.scenario = scenario(config.scenario)
        formulation = config.resolved
        self.intake = ExperienceIntake(config.store_capacity, formulation, on_refused=self._send_reject)
        self.version_mark = VersionMark(run_dir)
        self.state = PolicyState(
            self.scenario.n_robots,
            formulation.featurizer,
            self.scenario.name,
            self.scenario.action_steps,
            config.method,
            on_version=self.version_mark.record,
            reward=formulation.reward,
            act_every=formulation.act_every,
            actions=formulation.actions,
        )
        self.evaluator = Evaluator(self.scenario, config.eval_trials, config.eval_steps, config.final_eval_trials)
        self.checkpointer = Checkpointer(run_dir)
        self.fits = 0
        self._fitted_at = 0  # tuples received when the last fit took its data
        # An increment enters the ledger and the pending merge together, and a checkpoint snapshots both together:
        # otherwise a checkpoint could acknowledge an increment it does not hold, or hold one it does not acknowledge.
        self._sequence_lock = threading.Lock()
        self._checkpoint_lock = threading.Lock()  # the loop and a finished fit both checkpoint
        self._rejected_before: dict[str, int] = {}  # rejections counted before a resume, by type
        self._fitter: threading.Thread | None = None
        self._members_lock = threading.Lock()
        self._live: set[str] = set()
        self._seen: set[str] = set()
        self._elapsed_before = 0.0
        self._started = time.monotonic()
        self._rng = np.random.default_rng(config.seed)
        self._steps = 0  # status publishes so far: the monitor's learner_step timeline
        self._laid_out: list[str] | None = None  # actors in the viewer layout last sent
        self.monitor.use_clock(self.elapsed)  # the viewer's train_time is the run clock of the learning curve
        estimator()  # torch and scikit-learn load now, not at the first fit while the actors wait for a policy
        if resume:
            self._restore()

    # -- handlers (called by the transport's threads, see learner.wiring) -------------------------------------------

    def latest_policy(self) -> PolicyUpdate | None:
        return self.state.current

    def on_increment(self, msg: QTableIncrement) -> None:
        with self._sequence_lock:
            if self.intake.accept_sequence(msg.actor_id, msg.incarnation, msg.seq):
                self.state.add_increment(msg)

    def on_rejected(self, key: str, payload: bytes, error: ProtocolError) -> None:
        """A payload the transport refused on an actor's key: if it names its sender's stream and seq, it is
        rejected explicitly, so the stream flows on past it. Never for a payload that claims another sender's
        stream (a lie must not make the genuine sender drop its message)."""
        peeked = peek_sequence(payload)
        if peeked is None or peeked[0] != self.keys.owner(key):
            return
        actor, incarnation, seq = peeked
        with self._sequence_lock:
            first = self.intake.refuse(actor, incarnation, seq)
        if first:  # published outside the lock: a blocked publish must not hold up checkpoints
            self._send_reject(actor, incarnation, seq, f"{type(error).__name__}: {error}")

    def _send_reject(self, actor: str, incarnation: int, seq: int, reason: str) -> None:
        log.warning("rejected seq %d of %s (incarnation %x): %s", seq, actor, incarnation, reason)
        printable = "".join(c if c.isprintable() else "?" for c in reason)[:MAX_NAME_LEN]
        msg = Reject(actor_id=actor, incarnation=incarnation, seq=seq, reason=printable)
        self.transport.publish(self.keys.reject(actor), msg)

    def on_actor_join(self, key: str) -> None:
        actor = key.rsplit("/", 1)[-1]
        with self._members_lock:
            self._live.add(actor)
            self._seen.add(actor)
            live = len(self._live)
        log.info("actor %s joined (%d live)", actor, live)

    def on_actor_leave(self, key: str) -> None:
        actor = key.rsplit("/", 1)[-1]
        with self._members_lock:
            self._live.discard(actor)
            live = len(self._live)
        log.info("actor %s left (%d live)", actor, live)

    def announce(self) -> None:
        """Broadcast the restored policy at once (if resumed), so actors need not wait for the next merge."""
        current = self.state.current
        if current is not None:
            self.transport.publish(self.keys.policy(), current)
        log.info("learner %s started (policy version %d)", self.config.learner_id, self.state.version)

    # -- the loop ---------------------------------------------------------------------------------------------------

    def elapsed(self) -> float:
        return self._elapsed_before + time.monotonic() - self._started

    def run(self, stop: threading.Event) -> LearnerReport:
        c = self.config
        self._started = time.monotonic()
        if self.monitor.enabled:
            self.monitor.formulation(c.resolved.featurizer, self.state.reward)
            self._monitor_references()
        next_broadcast = next_checkpoint = next_status = self._started
        next_eval = self._started + c.eval_interval
        while not stop.is_set():
            if c.duration is not None and self.elapsed() >= c.duration:
                break
            self._maybe_fit()
            now = time.monotonic()
            fitted = self.state.fitted
            if fitted and now >= next_broadcast:
                self._broadcast()
                next_broadcast = now + c.broadcast_interval
            if now >= next_checkpoint:
                self.checkpoint()
                next_checkpoint = time.monotonic() + c.checkpoint_interval
            if fitted and now >= next_eval:
                self._evaluate()
                next_eval = time.monotonic() + c.eval_interval
            if now >= next_status:
                self._publish_status()
                next_status = now + c.status_interval
            stop.wait(0.05)
        return self._finish()

    def _maybe_fit(self) -> None:
        """Start phase 1 in the background when due; the loop keeps storing, acking and broadcasting meanwhile."""
        if self._fitter is not None and self._fitter.is_alive():
            return
        c = self.config
        if not self.state.fitted:
            due = len(self.intake) >= c.min_tuples
        else:
            due = c.refit_growth > 0 and self.intake.tuples_received >= c.refit_growth * self._fitted_at
        if due:
            self._fitter = threading.Thread(target=self._fit, name="phase1", daemon=True)
            self._fitter.start()

    def _fit(self) -> None:
        data, self._fitted_at = self.intake.snapshot_for_fit()
        warm_start = self.state.discretization
        log.info("phase 1 on %d tuples (%s)", len(data), "first fit" if warm_start is None else "warm start")
        began = time.monotonic()
        seed = int(self._rng.integers(2**31))
        disc: Discretization = phase1(
            data, N_ACTIONS, self.config.phase1, seed=seed, warm_start=warm_start
        ).discretization
        self.state.adopt(disc)
        self.fits += 1
        # On disk before its first broadcast: a resumed learner then knows every discretization it ever published.
        self.checkpoint()
        log.info(
            "phase 1 done in %.1f s: %.1f prototypes per action (%d cells)",
            time.monotonic() - began,
            disc.sizes().mean(),
            disc.size,
        )
        self._broadcast()
        policy = self.state.policy()
        if self.monitor.enabled and policy is not None:
            self._monitor_policy(policy)

    def _broadcast(self) -> None:
        self.transport.publish(self.keys.policy(), self.state.publish())

    def _evaluate(self) -> None:
        policy = self.state.policy()
        if policy is None:
            return
        coverage = self.evaluator.periodic(policy, at=self.elapsed())
        if self.monitor.enabled:
            self.monitor.eval_coverage(coverage, policy_version=policy.version, learner_step=self._steps)
            self._monitor_policy(policy)
        log.info("evaluation of policy version %d: %.2f%% of targets observed", policy.version, coverage)

    # -- status, checkpoints, report --------------------------------------------------------------------------------

    def status(self) -> LearnerStatus:
        figures = self.intake.figures()
        lag = self.state.lag(figures.latest_version)
        with self._members_lock:
            live = len(self._live)
        curve = self.evaluator.curve
        return LearnerStatus(
            tuples_received=figures.tuples_received,
            store_size=figures.store_size,
            overwritten=figures.overwritten,
            duplicates=figures.duplicates,
            gaps=figures.gaps,
            policy_version=self.state.version,
            live_actors=live,
            tuples_per_s=figures.tuples_per_s,
            policy_lag_max=max(lag.values(), default=0),
            rejected=sum(self.rejected_by_type().values()) + figures.rejected,
            coverage=curve[-1][1] if curve else -1.0,
            fits=self.fits,
            elapsed=self.elapsed(),
        )

    def rejected_by_type(self) -> dict[str, int]:
        """Messages refused by the transport over the whole run, by class (see docs/protocol.md)."""
        out = dict(self._rejected_before)
        for name, n in self.transport.stats.rejected.items():
            out[name] = out.get(name, 0) + n
        return out

    def _publish_status(self) -> None:
        status = self.status()
        msg = Status(
            sender=self.config.learner_id, role="learner", wall_time=time.time(), counters=status.to_counters()
        )
        self.transport.publish(self.keys.status(self.config.learner_id), msg)
        log.debug("status %s", status)
        self._steps += 1
        if self.monitor.enabled:
            self._monitor_status(status)

    def _monitor_status(self, status: LearnerStatus) -> None:
        with self._members_lock:
            actors = sorted(self._seen)
        if actors != self._laid_out:  # a new actor gets its arena view
            cfg = self.scenario
            self.monitor.send_blueprint(actors, arena_radius=cfg.arena_radius, sensing_range=cfg.sensing_range)
            self._laid_out = actors
        self.monitor.learner_metrics(
            learner_step=self._steps,
            policy_version=status.policy_version,
            tuples_per_s=status.tuples_per_s,
            live_actors=status.live_actors,
            store_size=status.store_size,
            rejected=status.rejected,
            lag=self.state.lag(self.intake.figures().latest_version),
        )

    def _monitor_references(self) -> None:
        """The hand-made controllers on the evaluator's own test trials: the levels the learning curve is read
        against, measured once: 0.4 s for the default 10 trials of 1000 steps, on 2 busy cores."""
        ev = self.evaluator
        began = time.monotonic()
        levels = {
            name: evaluate(ev.cfg, controller, ev.trials, ev.steps, seed=TEST_SEED).coverage_mean
            for name, controller in HAND_MADE.items()
        }
        self.monitor.reference_levels(levels)
        log.info("reference levels on the %d test trials (%.1f s): %s", ev.trials, time.monotonic() - began, levels)

    def _monitor_policy(self, policy: Policy) -> None:
        """Prototypes coloured by their Q value (mean over robots) and the tables' statistics."""
        prototypes, q_values = policy.prototypes_by_action()
        scale = policy.discretization.scale
        if scale is not None:  # drawn in arena units, so the views' range is the sensing range
            prototypes = [p * scale for p in prototypes]
        self.monitor.prototypes(prototypes, q_values, policy_version=policy.version)
        self.monitor.q_stats([policy.tables], policy_version=policy.version, learner_step=self._steps)

    def checkpoint(self) -> Path:
        """Write everything needed to resume, atomically, then acknowledge what it holds."""
        with self._checkpoint_lock:
            with self._sequence_lock:
                arrays, acks = self.intake.checkpoint_arrays()
                policy_arrays, policy_meta = self.state.to_arrays()
            with self._members_lock:
                seen = sorted(self._seen)
            meta = {
                **policy_meta,
                "fits": self.fits,
                "fitted_at": self._fitted_at,
                "coverage_curve": self.evaluator.curve,
                "elapsed": self.elapsed(),
                "rejected_by_type": self.rejected_by_type(),
                "seen_actors": seen,
                "config": dataclasses.asdict(self.config),
            }
            path = self.checkpointer.save({**arrays, **policy_arrays}, meta)
        for actor, incarnation, seq in acks:
            self.transport.publish(self.keys.ack(actor), Ack(actor_id=actor, incarnation=incarnation, seq=seq))
        return path

    def _restore(self) -> None:
        arrays, meta = self.checkpointer.load()
        self.intake.restore(arrays)
        self.state.restore(arrays, meta, published=self.version_mark.load())
        self.fits = int(meta["fits"])
        self._fitted_at = int(meta["fitted_at"])
        self._elapsed_before = float(meta["elapsed"])
        self.evaluator.curve = [(float(t), float(c)) for t, c in meta["coverage_curve"]]
        self._seen = set(meta["seen_actors"])
        self._rejected_before = {str(k): int(v) for k, v in meta["rejected_by_type"].items()}
        log.info(
            "resumed from %s: %d tuples stored, policy version %d",
            self.checkpointer.path,
            len(self.intake),
            self.state.version,
        )

    def _finish(self) -> LearnerReport:
        if self._fitter is not None:
            self._fitter.join()  # a fit under way finishes, so its work is in the final policy
        final = None
        if self.state.fitted:
            self._broadcast()
            policy = self.state.policy()
            assert policy is not None
            final = self.evaluator.final(policy)
            if self.monitor.enabled:
                self.monitor.final_coverage(
                    final, trials=self.config.final_eval_trials, policy_version=policy.version, learner_step=self._steps
                )
                self._monitor_policy(policy)
            log.info("final policy version %d: %.2f%% of targets observed", policy.version, final)
        self.checkpoint()
        policy = self.state.policy()
        policy_file = None if policy is None else str(save_policy(policy, self.scenario, self.run_dir / "policy.npz"))
        status = self.status()
        figures = self.intake.figures()
        disc = self.state.discretization
        with self._members_lock:
            seen, live = sorted(self._seen), sorted(self._live)
        report = LearnerReport(
            learner_id=self.config.learner_id,
            actors=seen,
            live_actors=live,
            tuples_received=status.tuples_received,
            tuples_by_actor=figures.tuples_by_actor,
            tuples_per_s=round(status.tuples_received / max(status.elapsed, 1e-9), 1),
            policy_version=status.policy_version,
            phase1_fits=self.fits,
            prototypes_per_action=[] if disc is None else [int(s) for s in disc.sizes()],
            duplicates=status.duplicates,
            gaps=status.gaps,
            rejected=status.rejected,
            rejected_by_type=self.rejected_by_type(),
            increments=self.state.increments,
            stale_increments=self.state.stale_increments,
            store_size=status.store_size,
            overwritten=status.overwritten,
            policy_lag=self.state.lag(figures.latest_version),
            final_coverage_mean=None if final is None else round(final, 3),
            final_eval_trials=self.config.final_eval_trials,
            eval_trials=self.config.eval_trials,
            coverage_curve=[list(p) for p in self.evaluator.curve],
            policy_file=policy_file,
            checkpoint=str(self.checkpointer.path),
            seconds=round(self.elapsed(), 2),
        )
        (self.run_dir / "report.json").write_text(json.dumps(report.to_dict(), indent=2))
        return report
