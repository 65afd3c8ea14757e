"""The central ENNC-QL learner service.

Call sequence (``run_learner`` wires it to a Zenoh transport; tests can use an in-memory one)::

    service = LearnerService(transport, LearnerConfig(), run_dir=Path("runs/x"))
    service.start()               # subscriptions, queryable for late joiners, liveliness; restores a checkpoint
    report = service.run(stop)    # until stop / duration: phase 1, merges, broadcasts, evaluation, checkpoints
    service.close()

Experience is de-duplicated by (actor, incarnation, seq) into a bounded store; it is acknowledged only once a
checkpoint holding it is on disk, so an actor's outbox covers a learner crash. Phase 1 runs when ``min_tuples``
are stored and again, warm-started, each time the store has grown by ``refit_growth`` times. The actors' Q-table
increments (changes since their previous increment) are merged cell by cell, weighted by the visits behind them,
and the tables broadcast with a strictly increasing version.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.discretization import Discretization
from algorithm.phase1 import Phase1Config, phase1
from algorithm.policy import Policy, PolicyController
from algorithm.policy_file import save_policy
from learner.ingest import Ingest
from learner.store import ExperienceStore, SequenceLedger
from monitor import Monitor
from protocol import Ack, ExperienceBatch, PolicyUpdate, QTableIncrement, Status, Transport
from sim import FEATURIZERS, N_ACTIONS, evaluate, scenario

log = logging.getLogger(__name__)

CHECKPOINT = "checkpoint.npz"


@dataclass(frozen=True, slots=True)
class LearnerConfig:
    learner_id: str = "learner"
    scenario: str = "cmommt-v1"
    featurizer: str = "collab6d"
    store_capacity: int = 1_000_000
    """Tuples kept; the oldest are overwritten beyond it (counted)."""
    min_tuples: int = 150_000
    """Tuples stored before the first phase 1."""
    refit_growth: float = 0.0
    """Refit (warm-started) whenever the tuples received have grown this many times since the last fit; 0 = never."""
    phase1: Phase1Config = field(default_factory=lambda: Phase1Config(max_iterations=1, max_patterns=30_000))
    broadcast_interval: float = 3.0
    """Seconds between merges + policy broadcasts."""
    eval_interval: float = 20.0
    """Seconds between evaluations of the current policy."""
    eval_trials: int = 10
    """Test trials of the periodic evaluations (the learning curve), as the paper scores one process [paper]."""
    final_eval_trials: int = 50
    """Test trials of the final policy's figure: as many as behind each figure of the paper (5 learning processes
    x 10 trials), since one run of ten trials varies by a few points from one set of trials to another [choice]."""
    eval_steps: int = 1000
    checkpoint_interval: float = 5.0
    """Seconds between checkpoints; acknowledgements follow each checkpoint."""
    status_interval: float = 2.0
    duration: float | None = None
    """Stop after this many seconds (None: until stopped)."""
    seed: int = 0


class LearnerService:
    def __init__(
        self,
        transport: Transport,
        config: LearnerConfig,
        run_dir: Path,
        resume: bool = False,
        monitor: Monitor | None = None,
    ) -> None:
        if config.featurizer not in FEATURIZERS:
            raise ValueError(f"unknown featurizer {config.featurizer!r}")
        self.transport = transport
        self.monitor = monitor or Monitor()
        self.keys = transport.keys
        self.config = config
        self.run_dir = run_dir
        self.cfg = scenario(config.scenario)
        self.ingest = Ingest(ExperienceStore(config.store_capacity, FEATURIZERS[config.featurizer]))
        self.lock = threading.Lock()  # guards the policy state below and the pending increments
        self.disc: Discretization | None = None
        self.disc_id = 0
        self.disc_of_version: dict[int, int] = {}
        self.tables = np.zeros((self.cfg.n_robots, 0))
        self.visits = np.zeros((self.cfg.n_robots, 0), np.uint64)
        self.version = 0
        self.current: PolicyUpdate | None = None
        self.pending: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]] = {}
        self.fitted_at = 0
        self.fits = 0
        self.increments = 0
        self.stale_increments = 0
        self.live: set[str] = set()
        self.seen_actors: set[str] = set()
        self.coverage_curve: list[tuple[float, float]] = []
        self.elapsed_before = 0.0
        self.rng = np.random.default_rng(config.seed)
        self._fitter: threading.Thread | None = None
        self._handles: list[Any] = []
        self._steps = 0  # status publishes so far: the monitor's learner_step timeline
        self._laid_out: list[str] | None = None  # actors in the viewer layout last sent
        if resume:
            self._restore()

    # -- wiring -------------------------------------------------------------------------------------------------

    def start(self) -> None:
        t, keys = self.transport, self.keys
        self._handles.append(t.subscribe(keys.experience(), ExperienceBatch, self.ingest.on_experience))
        self._handles.append(t.subscribe(keys.qinc(), QTableIncrement, self._on_increment))
        self._handles.append(t.declare_queryable(keys.policy_latest(), self._latest))
        self._handles.append(t.liveliness_subscribe(keys.alive("actor"), self._on_join, self._on_leave))
        self._handles.append(t.liveliness_token(keys.alive("learner", self.config.learner_id)))
        if self.current is not None:
            t.publish(keys.policy(), self.current)
        log.info("learner %s started (policy version %d)", self.config.learner_id, self.version)

    def close(self) -> None:
        for handle in reversed(self._handles):
            handle.close()
        self._handles.clear()

    def _latest(self) -> PolicyUpdate | None:
        with self.lock:
            return self.current

    def _on_join(self, key: str) -> None:
        actor = key.rsplit("/", 1)[-1]
        with self.lock:
            self.live.add(actor)
            self.seen_actors.add(actor)
        log.info("actor %s joined (%d live)", actor, len(self.live))

    def _on_leave(self, key: str) -> None:
        actor = key.rsplit("/", 1)[-1]
        with self.lock:
            self.live.discard(actor)
        log.info("actor %s left (%d live)", actor, len(self.live))

    def _on_increment(self, msg: QTableIncrement) -> None:
        if not self.ingest.accept_sequence(msg.actor_id, msg.incarnation, msg.seq):
            return
        with self.lock:
            self.increments += 1
            current_disc = self.disc_of_version.get(int(msg.policy_version))
            if current_disc != self.disc_id or msg.robot >= self.cfg.n_robots or msg.q.size != self.tables.shape[1]:
                self.stale_increments += 1  # over an older discretization: its cells mean something else now
                return
            key = (msg.actor_id, int(msg.robot))
            change = np.array(msg.q, np.float64)
            visits = np.asarray(msg.visits, np.float64)
            previous = self.pending.get(key)
            if previous is not None:  # successive increments of one actor add up
                change, visits = change + previous[0], visits + previous[1]
            self.pending[key] = (change, visits)

    # -- the loop -----------------------------------------------------------------------------------------------

    def elapsed(self, start: float) -> float:
        return self.elapsed_before + time.monotonic() - start

    def run(self, stop: threading.Event) -> dict[str, Any]:
        start = time.monotonic()
        c = self.config
        next_broadcast = next_checkpoint = next_status = start
        next_eval = start + c.eval_interval
        while not stop.is_set():
            if c.duration is not None and self.elapsed(start) >= c.duration:
                break
            self._maybe_fit()
            now = time.monotonic()
            if self.disc is not None and now >= next_broadcast:
                self._merge_and_broadcast()
                next_broadcast = now + c.broadcast_interval
            if now >= next_checkpoint:
                self.checkpoint()
                next_checkpoint = time.monotonic() + c.checkpoint_interval
            if self.disc is not None and now >= next_eval:
                self._evaluate(start)
                next_eval = time.monotonic() + c.eval_interval
            if now >= next_status:
                self._publish_status(start)
                next_status = now + c.status_interval
            stop.wait(0.05)
        return self._finish(start)

    def _maybe_fit(self) -> None:
        """Start phase 1 in the background when due; the loop keeps storing, acking and broadcasting meanwhile."""
        if self._fitter is not None and self._fitter.is_alive():
            return
        c = self.config
        if self.disc is None:
            due = len(self.ingest.store) >= c.min_tuples
        else:
            due = c.refit_growth > 0 and self.ingest.tuples_received >= c.refit_growth * self.fitted_at
        if due:
            self._fitter = threading.Thread(target=self._fit, args=(self.disc is not None,), name="phase1", daemon=True)
            self._fitter.start()

    def _fit(self, warm: bool) -> None:
        with self.ingest.lock:
            data = self.ingest.store.view()
            self.fitted_at = self.ingest.tuples_received
        log.info("phase 1 on %d tuples (%s)", len(data), "warm start" if warm else "first fit")
        began = time.monotonic()
        with self.lock:
            warm_start = self.disc if warm else None
        result = phase1(data, N_ACTIONS, self.config.phase1, seed=int(self.rng.integers(2**31)), warm_start=warm_start)
        disc = result.discretization
        with self.lock:
            if self.disc is None:
                tables = np.tile(disc.labels.astype(np.float64), (self.cfg.n_robots, 1))
            else:
                self._merge_pending()
                tables = disc.carry_over(self.disc, self.tables)
            self.disc = disc
            self.disc_id += 1
            self.tables = tables
            self.visits = np.zeros(tables.shape, np.uint64)
            self.pending.clear()
            self.fits += 1
        log.info(
            "phase 1 done in %.1f s: %.1f prototypes per action (%d cells)",
            time.monotonic() - began,
            disc.sizes().mean(),
            disc.size,
        )
        self._merge_and_broadcast()
        if self.monitor.enabled:
            policy = self.policy()
            assert policy is not None
            self._monitor_policy(policy)

    def _merge_pending(self) -> None:
        """Add, cell by cell, the visit-weighted mean of the changes each actor made to a robot's table.

        With one actor per robot this applies its changes exactly; several actors learning one robot move each
        cell by the mean of their changes, weighted by how often each visited it. The caller holds the lock.
        """
        by_robot: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        for (_, robot), entry in self.pending.items():
            by_robot.setdefault(robot, []).append(entry)
        for robot, entries in by_robot.items():
            change = np.stack([e[0] for e in entries])
            weight = np.stack([e[1] for e in entries])
            total = weight.sum(axis=0)
            visited = total > 0
            self.tables[robot, visited] += (change * weight).sum(axis=0)[visited] / total[visited]
            self.visits[robot] += total.astype(np.uint64)
        self.pending.clear()

    def _merge_and_broadcast(self) -> None:
        with self.lock:
            assert self.disc is not None
            self._merge_pending()
            self.version += 1
            self.disc_of_version[self.version] = self.disc_id
            update = self._policy_message()
            self.current = update
        self.transport.publish(self.keys.policy(), update)

    def policy(self) -> Policy | None:
        with self.lock:
            if self.disc is None:
                return None
            return Policy(
                featurizer=self.config.featurizer,
                discretization=self.disc,
                tables=self.tables.astype(np.float32),
                robot_table=np.arange(self.cfg.n_robots),
                action_steps=self.cfg.action_steps,
                visits=self.visits.copy(),
                version=self.version,
                method="ennc-ql-collab-option2" if self.config.featurizer == "collab6d" else "ennc-ql-local",
            )

    def _evaluate(self, start: float, trials: int | None = None) -> float | None:
        policy = self.policy()
        if policy is None:
            return None
        periodic = trials is None
        trials = trials or self.config.eval_trials
        result = evaluate(self.cfg, PolicyController(policy), trials, self.config.eval_steps, seed=0)
        if periodic:  # the curve keeps one protocol; the final figure is reported on its own
            self.coverage_curve.append((round(self.elapsed(start), 2), round(result.coverage_mean, 3)))
        if self.monitor.enabled:
            self.monitor.eval_coverage(result.coverage_mean, policy_version=policy.version, learner_step=self._steps)
            self._monitor_policy(policy)
        log.info("evaluation of policy version %d: %.2f%% of targets observed", policy.version, result.coverage_mean)
        return result.coverage_mean

    # -- status, checkpoints, report ----------------------------------------------------------------------------

    def counters(self, start: float) -> dict[str, float]:
        ingest = self.ingest
        with ingest.lock:
            lag = [self.version - v for v in ingest.latest_version.values()]
            figures = {
                "tuples_received": ingest.tuples_received,
                "store_size": len(ingest.store),
                "overwritten": ingest.store.overwritten,
                "duplicates": ingest.ledger.duplicates,
                "gaps": ingest.ledger.gaps,
            }
        stats = self.transport.stats
        return {
            **{k: float(v) for k, v in figures.items()},
            "policy_version": float(self.version),
            "live_actors": float(len(self.live)),
            "tuples_per_s": ingest.tuples_per_s(),
            "policy_lag_max": float(max(lag, default=0)),
            "rejected": float(sum(stats.rejected.values()) + ingest.rejected),
            "coverage": self.coverage_curve[-1][1] if self.coverage_curve else -1.0,
            "fits": float(self.fits),
            "elapsed": self.elapsed(start),
        }

    def _publish_status(self, start: float) -> None:
        counters = self.counters(start)
        status = Status(sender=self.config.learner_id, role="learner", wall_time=time.time(), counters=counters)
        self.transport.publish(self.keys.status(self.config.learner_id), status)
        log.debug("status %s", counters)
        self._steps += 1
        self._monitor_status(counters)

    def _monitor_status(self, counters: dict[str, float]) -> None:
        monitor = self.monitor
        if not monitor.enabled:
            return
        with self.lock:
            actors = sorted(self.seen_actors)
        if actors != self._laid_out:  # a new actor gets its arena view
            monitor.send_blueprint(actors, N_ACTIONS)
            self._laid_out = actors
        with self.ingest.lock:
            lag = {actor: self.version - v for actor, v in self.ingest.latest_version.items()}
        monitor.learner_metrics(
            learner_step=self._steps,
            policy_version=self.version,
            tuples_per_s=counters["tuples_per_s"],
            live_actors=int(counters["live_actors"]),
            store_size=int(counters["store_size"]),
            rejected=int(counters["rejected"]),
            lag=lag,
        )

    def _monitor_policy(self, policy: Policy) -> None:
        """Prototypes coloured by their Q value (mean over robots) and the tables' statistics."""
        prototypes, q_values = policy.prototypes_by_action()
        self.monitor.prototypes(prototypes, q_values, policy_version=policy.version)
        self.monitor.q_stats([policy.tables], policy_version=policy.version, learner_step=self._steps)

    def checkpoint(self) -> Path:
        """Write everything needed to resume, atomically, then acknowledge what it holds."""
        with self.ingest.lock:
            arrays = {**self.ingest.store.to_arrays(), **self.ingest.ledger.to_arrays()}
            acks = [
                (s, inc, st.contiguous) for (s, inc), st in self.ingest.ledger.streams.items() if st.contiguous >= 0
            ]
            received = self.ingest.tuples_received
            by_actor = dict(self.ingest.tuples_by_actor)
        with self.lock:
            meta = {
                "tuples_by_actor": by_actor,
                "version": self.version,
                "disc_id": self.disc_id,
                "fits": self.fits,
                "fitted_at": self.fitted_at,
                "tuples_received": received,
                "coverage_curve": self.coverage_curve,
                "elapsed": self.elapsed_before,
                "seen_actors": sorted(self.seen_actors),
                "config": asdict(self.config),
            }
            if self.disc is not None:
                arrays.update(
                    prototypes=self.disc.prototypes,
                    labels=self.disc.labels,
                    offsets=self.disc.offsets,
                    tables=self.tables,
                    visits=self.visits,
                )
                if self.disc.scale is not None:
                    arrays["scale"] = self.disc.scale
        arrays["meta"] = np.frombuffer(json.dumps(meta, default=str).encode(), np.uint8)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        path = self.run_dir / CHECKPOINT
        fd, tmp = tempfile.mkstemp(dir=self.run_dir, prefix=".checkpoint.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, **arrays)  # type: ignore[arg-type]
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        for actor, incarnation, seq in acks:
            self.transport.publish(self.keys.ack(actor), Ack(actor_id=actor, incarnation=incarnation, seq=seq))
        return path

    def _restore(self) -> None:
        path = self.run_dir / CHECKPOINT
        if not path.exists():
            raise FileNotFoundError(f"--resume: no checkpoint at {path}")
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
        meta = json.loads(arrays["meta"].tobytes().decode())
        self.ingest.store = ExperienceStore.from_arrays(arrays, self.config.store_capacity)
        self.ingest.ledger = SequenceLedger.from_arrays(arrays)
        self.ingest.tuples_received = int(meta["tuples_received"])
        self.ingest.tuples_by_actor.update({k: int(v) for k, v in meta["tuples_by_actor"].items()})
        self.version = int(meta["version"])
        self.disc_id = int(meta["disc_id"])
        self.fits = int(meta["fits"])
        self.fitted_at = int(meta["fitted_at"])
        self.elapsed_before = float(meta["elapsed"])
        self.coverage_curve = [(float(t), float(c)) for t, c in meta["coverage_curve"]]
        self.seen_actors = set(meta["seen_actors"])
        if "prototypes" in arrays:
            self.disc = Discretization(arrays["prototypes"], arrays["labels"], arrays["offsets"], arrays.get("scale"))
            self.tables = arrays["tables"].astype(np.float64)
            self.visits = arrays["visits"].astype(np.uint64)
            # The restored tables are broadcast as a new version over the same discretization.
            self.version += 1
            self.disc_of_version[self.version] = self.disc_id
            self.current = self._policy_message()
        log.info("resumed from %s: %d tuples stored, policy version %d", path, len(self.ingest.store), self.version)

    def _policy_message(self) -> PolicyUpdate:
        """The current policy as a broadcast message; the caller holds ``self.lock``."""
        assert self.disc is not None
        return PolicyUpdate(
            version=self.version,
            scenario=self.cfg.name,
            featurizer=self.config.featurizer,
            action_steps=self.cfg.action_steps,
            prototypes=self.disc.prototypes.astype(np.float32),
            labels=self.disc.labels.astype(np.float32),
            offsets=self.disc.offsets.astype(np.int64),
            robots=np.arange(self.cfg.n_robots, dtype=np.int16),
            q_tables=self.tables.astype(np.float32),
            visits=np.minimum(self.visits, np.iinfo(np.uint32).max).astype(np.uint32),
            scale=np.ones(self.disc.dim, np.float32) if self.disc.scale is None else self.disc.scale.astype(np.float32),
        )

    def _finish(self, start: float) -> dict[str, Any]:
        if self._fitter is not None:
            self._fitter.join()  # a fit under way finishes, so its work is in the final policy
        if self.disc is not None:
            self._merge_and_broadcast()
        final = self._evaluate(start, self.config.final_eval_trials) if self.disc is not None else None
        self.checkpoint()
        policy = self.policy()
        policy_file = None
        if policy is not None:
            policy_file = str(save_policy(policy, self.cfg, self.run_dir / "policy.npz"))
        counters = self.counters(start)
        with self.lock:
            lag = {a: self.version - v for a, v in self.ingest.latest_version.items()}
            report = {
                "learner_id": self.config.learner_id,
                "actors": sorted(self.seen_actors),
                "live_actors": sorted(self.live),
                "tuples_received": int(counters["tuples_received"]),
                "tuples_by_actor": dict(self.ingest.tuples_by_actor),
                "tuples_per_s": round(counters["tuples_per_s"], 1),
                "policy_version": self.version,
                "phase1_fits": self.fits,
                "prototypes_per_action": [] if self.disc is None else [int(s) for s in self.disc.sizes()],
                "duplicates": int(counters["duplicates"]),
                "gaps": int(counters["gaps"]),
                "rejected": int(counters["rejected"]),
                "rejected_by_type": dict(self.transport.stats.rejected),
                "increments": self.increments,
                "stale_increments": self.stale_increments,
                "store_size": int(counters["store_size"]),
                "overwritten": int(counters["overwritten"]),
                "policy_lag": lag,
                "final_coverage_mean": None if final is None else round(final, 3),
                "final_eval_trials": self.config.final_eval_trials,
                "eval_trials": self.config.eval_trials,
                "coverage_curve": [list(p) for p in self.coverage_curve],
                "policy_file": policy_file,
                "checkpoint": str(self.run_dir / CHECKPOINT),
                "seconds": round(self.elapsed(start), 2),
            }
        (self.run_dir / "report.json").write_text(json.dumps(report, indent=2))
        return report
