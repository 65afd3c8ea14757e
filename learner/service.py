"""The central ENNC-QL learner: the loop that ties intake, fits, policy state, evaluation and checkpoints together.

Call sequence (``learner.wiring.connect`` holds every subscription; tests and serial mode use the in-memory
transport)::

    service = LearnerService(transport, LearnerConfig(), run_dir=Path("runs/x"), resume=False)
    with connect(service, transport):       # subscriptions, late-joiner queryable, liveliness (one ExitStack)
        report = service.run(stop)          # until stop / duration: fits, merges, broadcasts, evaluations, checkpoints

Experience is de-duplicated by (actor, incarnation, seq) into a bounded store (``learner.intake``, which also
rejects what it refuses for good); it is acknowledged only once a checkpoint holding it is on disk, so an actor's
outbox covers a learner crash. Phase 1 runs in the background when due (``learner.fitting``). The actors' Q-table
increments are merged cell by cell, weighted by the visits behind them, and the tables broadcast with a strictly
increasing version (``learner.policy_state``). Membership comes from liveliness tokens (``learner.membership``),
the viewer's figures go through a ``monitor.learner.LearnerWatch``, and the figures are typed in
``learner.report``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import psutil

from algorithm.discretization import Discretization
from algorithm.files import write_atomic
from algorithm.phase1 import estimator
from algorithm.policy import Policy, PolicyController
from algorithm.policy_file import PolicyFileError, load_policy, save_policy
from algorithm.selection import (
    VALIDATION_SEED,
    BestPolicy,
    MarginChoice,
    ScoringStopped,
    choose_margin,
    rank,
    reference_spread,
)
from learner.checkpoint import Checkpointer, CheckpointError, VersionMark
from learner.config import LearnerConfig
from learner.evaluator import Evaluator
from learner.fitting import EXPLORATION, Fitter
from learner.intake import ExperienceIntake
from learner.membership import Membership
from learner.policy_state import PolicyState
from learner.report import LearnerReport, LearnerStatus
from monitor import Monitor
from monitor.learner import LearnerWatch
from protocol import Ack, QTableIncrement, Status, Transport
from sim import evaluate, scenario

log = logging.getLogger(__name__)

BEST_POLICY = "best-policy.npz"
"""The run folder's copy of the policy ``keep_best`` holds, written when it changes, so a resumed learner has it."""
EARLY_POLICY = "early-policy.npz"
"""The same for the early candidate (``early_window``) of the draw under way."""
DRAWN_POLICY = "drawn-policy.npz"
"""The same for the early candidate that scored best on the margin's validation trials over the draws so far."""
DRAWS = "draws"
"""The run folder's folder of every closed window's early candidate, ``draw-<k>.npz``, read with its margin, so that
a user can score each draw's candidate as the learner chose it, not only the best."""


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
        self.fitter = Fitter(
            config, on_fitted=self._adopt, exploration=run_dir / EXPLORATION if config.drawing else None
        )
        self.evaluator = Evaluator(self.scenario, config.eval_trials, config.eval_steps, config.final_eval_trials)
        self.keeper = None
        if config.keep_best:
            self.keeper = BestPolicy(self.scenario, config.validation_trials, config.eval_steps)
        self.early = None
        if config.keep_best and config.early_window > 0:
            self.early = BestPolicy(self.scenario, config.early_trials, config.eval_steps)
        self._window_at: float | None = None
        """The run clock at the first policy of the draw under way: where its early window starts."""
        self._early_version = 0
        self._draw = 0
        """The draw under way (0: the first fit's; ``draws``)."""
        self._window_scored = False
        """Whether the early candidate of the draw under way was scored once its window closed."""
        self._drawn: _Scored | None = None
        """The early candidate that scored best on the margin's validation trials over the windows closed so far, so
        the wind-down (which a SIGTERM under SLURM gives KillWait seconds) scores only the kept policy."""
        self.draws: list[dict[str, Any]] = []
        """Each closed window's early candidate as scored (``draw``, ``version``, ``at_s``, ``validation_coverage``,
        a margin choice's ``margin``, ``prototypes_per_action``)."""
        # The fit's thread adopts a draw while the loop may be scoring a window: the draw's bookkeeping changes under
        # this lock, so a window is never scored half-way into the next draw.
        self._draw_lock = threading.Lock()
        self.margin: MarginChoice | None = None
        """The law margin chosen at the end on validation trials (``law_margin`` none, a law action set)."""
        self._selected: Policy | None = None
        """The policy chosen at the end among the kept one and the early candidate."""
        self.candidates: list[dict[str, Any]] = []
        """When the early candidate and the kept policy were both scored: each one's figures."""
        self.spread_cap: float | None = None
        """``spread_cap``'s robots per covered target on the margin's validation trials, once scored (:meth:`_cap`)."""
        self.checkpointer = Checkpointer(run_dir)
        # The viewer's train_time is the run clock of the learning curve.
        self.watch = LearnerWatch(monitor or Monitor(), self.scenario, clock=self.elapsed)
        # An increment enters the ledger and the pending merge together, and a checkpoint snapshots both together:
        # otherwise a checkpoint could acknowledge an increment it does not hold, or hold one it does not acknowledge.
        self._sequence_lock = threading.Lock()
        self._checkpoint_lock = threading.Lock()  # the loop and a finished fit both checkpoint
        # The loop and a finished fit both broadcast: a version is numbered and sent under one lock, or the later
        # version could go on the wire first and the actors would see the versions go down.
        self._broadcast_lock = threading.Lock()
        self._elapsed_before = 0.0
        self._started = time.monotonic()
        self._stop = threading.Event()
        """The run's stop (:meth:`run`'s): a window's scoring gives up and no draw starts once it is set."""
        self._stopped_at: float | None = None
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
        self._stop = stop
        self._started = time.monotonic()
        self.watch.started(c.resolved, self.evaluator.references)
        next_broadcast = next_status = self._started
        next_eval = self._started + c.eval_interval
        with _Checkpoints(self.checkpoint, c.checkpoint_interval) as checkpoints:
            while not stop.is_set() and checkpoints.failure is None:
                if c.duration is not None and self.elapsed() >= c.duration:
                    break
                self.fitter.poll(self.intake, self.state.discretization)
                now = time.monotonic()
                fitted = self.state.fitted
                if fitted and now >= next_broadcast:
                    self._broadcast()
                    next_broadcast = now + c.broadcast_interval
                    self._offer_early()
                if fitted and now >= next_eval:
                    self._evaluate()
                    next_eval = time.monotonic() + c.eval_interval
                if now >= next_status:
                    self._publish_status()
                    next_status = now + c.status_interval
                stop.wait(0.05)
        self._stopped_at = self.elapsed()
        return self._finish()

    def _adopt(self, disc: Discretization, draw: bool = False) -> None:
        """A fit's new discretization (on the fit's thread): on disk before its first broadcast, so a resumed
        learner knows every discretization it ever published. A ``draw``'s tables start from its labels and its
        early window opens."""
        with self._draw_lock:
            if draw and self._stopped_at is not None:
                log.info("draw %d finished after training stopped: not adopted", self._draw + 1)
                return
            with self._checkpoint_lock:
                self.state.adopt(disc, fresh=draw)
                if self._window_at is None or draw:
                    self._window_at = self.elapsed()
                if draw:
                    self._draw += 1
                    self._window_scored = False
                    self._early_version = 0
                    self.early = BestPolicy(self.scenario, self.config.early_trials, self.config.eval_steps)
                    log.info("draw %d adopted: %.1f prototypes per action", self._draw, disc.sizes().mean())
        self.checkpoint()
        self._broadcast()
        policy = self.state.policy()
        if policy is not None:
            self.watch.policy(policy)

    def _broadcast(self) -> None:
        with self._broadcast_lock:
            self.transport.publish(self.transport.keys.policy(), self.state.publish())

    def _evaluate(self) -> None:
        policy = self.state.policy()
        if policy is None:
            return
        coverage = self.evaluator.periodic(policy, at=self.elapsed())
        levels = self.evaluator.references()
        spread = {"learned": {"coverage": coverage, **self.evaluator.spread}}
        for name, figures in self.evaluator.reference_spread().items():
            spread[name] = {"coverage": levels[name], **figures}
        self.watch.evaluated(policy, coverage, spread, trials=self.config.eval_trials)
        log.info("evaluation of policy version %d: %.2f%% of targets observed", policy.version, coverage)
        self._offer(policy)

    def _offer(self, policy: Policy) -> None:
        """Score ``policy`` on the validation trials; a new best goes to disk before the checkpoint that names it."""
        if self.keeper is None:
            return
        at = self.elapsed()
        validation = self.keeper.score(policy)
        # Recorded under the checkpoint's lock: no checkpoint names a best policy whose file is not written yet.
        with self._checkpoint_lock:
            if self.keeper.keep(policy, validation, at):
                save_policy(policy, self.scenario, self.run_dir / BEST_POLICY)
        log.info("validation of policy version %d: %.2f%% of targets observed", policy.version, validation)

    def _offer_early(self) -> None:
        """Within ``early_window`` seconds of a draw's first policy: score each new version for its early candidate;
        a new best goes to disk before the checkpoint that names it. Once the window closed: score the candidate on
        the margin's validation trials, then start the next draw if one is left and its window can close in time."""
        with self._draw_lock:
            if self.early is None or self._window_at is None:
                return
            at = self.elapsed()
            if at - self._window_at > self.config.early_window:
                if not self._window_scored:
                    self._close_window()
                self._next_draw(at)
                return
            policy = self.state.policy()
            if policy is None or policy.version == self._early_version:
                return
            self._early_version = policy.version
            validation = self.early.score(self._read(policy, None, self.config.early_margin))
            with self._checkpoint_lock:
                if self.early.keep(policy, validation, at):
                    save_policy(policy, self.scenario, self.run_dir / EARLY_POLICY)
            log.info("early validation of policy version %d: %.2f%% of targets observed", policy.version, validation)

    def _close_window(self) -> None:
        """Score the closed window's early candidate on the margin's validation trials; the best over the draws goes
        to disk before the checkpoint that names it. A stop gives the scoring up where an earlier draw's candidate is
        there to choose by (the first draw's would be scored in the wind-down anyway), so the wind-down fits a
        SIGTERM's grace."""
        assert self.early is not None
        best = self.early.best
        stop = None if self._drawn is None else self._stop
        try:
            scored = (
                None
                if best is None
                else _Scored("early", best.policy, best.at, *self._score(best.policy, stop), self._draw)
            )
        except ScoringStopped:
            log.info("draw %d: training stopped while its candidate was scored", self._draw)
            return
        with self._checkpoint_lock:
            self._window_scored = True
            if scored is None:
                return
            self.draws.append(scored.summary() | {"prototypes_per_action": _prototypes(scored.policy)})
            save_policy(
                self._read(scored.policy, scored.margin), self.scenario, self.run_dir / DRAWS / f"draw-{self._draw}.npz"
            )
            if self._drawn is None or scored.rank(self._cap()) > self._drawn.rank(self._cap()):  # earlier on a tie
                save_policy(scored.policy, self.scenario, self.run_dir / DRAWN_POLICY)
                self._drawn = scored
        log.info(
            "draw %d: early candidate version %d scores %.2f%% on %d validation trials, %.3f robots per covered "
            "target (best draw %d)",
            self._draw,
            scored.policy.version,
            scored.coverage,
            self.config.margin_trials,
            scored.spread,
            self._drawn.draw,
        )

    def _next_draw(self, at: float) -> None:
        """Start the next draw when one is left and its window can close before the run's duration, judged by the
        last fit's seconds."""
        c = self.config
        if self._draw + 1 >= c.draws or self.fitter.busy or self._stop.is_set():
            return
        if c.duration is not None and at + self.fitter.fit_s + c.early_window >= c.duration:
            return
        if self.fitter.draw(self._draw + 1):
            log.info("draw %d: phase 1 afresh on the first fit's tuples", self._draw + 1)

    def _kept_or_last(self) -> Policy | None:
        if self.keeper is not None and self.keeper.best is not None:
            return self.keeper.best.policy
        return self.state.policy()

    def _chosen(self) -> Policy | None:
        """The policy the run saves and scores: the one chosen at the end, else the best on the validation trials
        with ``keep_best``, else the last; read with the law margin (a law action set's)."""
        policy = self._selected if self._selected is not None else self._kept_or_last()
        return None if policy is None else self._read(policy, self.margin)

    def _read(self, policy: Policy, margin: MarginChoice | None, unchosen: float | None = None) -> Policy:
        """``policy`` as it is scored: a law action set's read with the margin chosen, else with ``law_margin``, else
        (none given) with ``unchosen``."""
        if policy.formulation.actions.law is None:
            return policy
        chosen = self.config.law_margin if margin is None else margin.margin
        chosen = unchosen if chosen is None else chosen
        return policy if chosen is None else dataclasses.replace(policy, law_margin=chosen)

    def _select(self) -> None:
        """The policy the run saves: the kept one (or the last), or the early candidate where that scores more on
        ``margin_trials`` validation trials; a law action set's read with the margin that scores best (``law_margin``
        none) or with the one given."""
        kept = self._kept_or_last()
        if kept is None:
            return
        at = self.elapsed() if self.keeper is None or self.keeper.best is None else self.keeper.best.at
        early = self._early_candidate()
        if early is not None and early.policy.version == kept.version:
            early = None
        if early is None and not self._chooses_margin(kept):
            return
        scored = [_Scored("kept", kept, at, *self._score(kept)), *([] if early is None else [early])]
        best = max(scored, key=lambda c: c.rank(self._cap()))  # the first of the best: the kept policy on a tie
        self._selected, self.margin = best.policy, best.margin
        if len(scored) > 1:
            self.candidates = [c.figures(chosen=c is best) for c in scored]
            log.info("saving the %s policy (version %d)", best.source, best.policy.version)

    def _early_candidate(self) -> _Scored | None:
        """The best draw's early candidate as scored when its window closed; before any window closed, the first
        draw's as it stands, scored now. A later draw's window still open is no candidate: scoring it too would
        double the wind-down."""
        best = None if self.early is None else self.early.best
        if best is not None and not self._window_scored:
            if self._drawn is None:
                return _Scored("early", best.policy, best.at, *self._score(best.policy), self._draw)
            log.info("draw %d's candidate was not scored when training stopped: it is no candidate", self._draw)
        return self._drawn

    def _chooses_margin(self, policy: Policy) -> bool:
        return self.config.law_margin is None and policy.formulation.actions.law is not None

    def _score(self, policy: Policy, stop: threading.Event | None = None) -> tuple[float, MarginChoice | None, float]:
        """``policy``'s coverage and robots per covered target on ``margin_trials`` validation trials: read with the
        law margin the run chooses (and that choice, held to the spread cap), else as :meth:`_chosen` reads it.
        ScoringStopped once ``stop`` is set, before a margin."""
        trials = self.config.margin_trials
        if self._chooses_margin(policy):
            cap = self._cap()
            log.info("choosing the law margin of policy version %d on %d validation trials", policy.version, trials)
            margin = choose_margin(self.scenario, policy, trials, self.config.eval_steps, stop=stop, cap=cap)
            tried = ", ".join(f"{m:g} {c:.2f}% ({margin.spreads[m]:.3f})" for m, c in margin.scores.items())
            log.info("law margin %g: %s", margin.margin, tried)
            return margin.scores[margin.margin], margin, margin.spreads[margin.margin]
        controller = PolicyController(self._read(policy, None))
        result = evaluate(self.scenario, controller, trials, self.config.eval_steps, seed=VALIDATION_SEED)
        spread = result.robots_per_covered_target
        log.info("policy version %d: %.2f%% on %d validation trials", policy.version, result.coverage_mean, trials)
        return result.coverage_mean, None, spread

    def _cap(self) -> float | None:
        """The robots per covered target that hold the run's choices: ``spread_cap``'s team on the margin's
        validation trials, scored at the first choice (on the loop's thread, as every choice is)."""
        name = self.config.spread_cap
        if name is not None and self.spread_cap is None:
            trials = self.config.margin_trials
            self.spread_cap = reference_spread(self.scenario, name, trials, self.config.eval_steps)
            cap = self.spread_cap
            log.info("choices held to %s's %.4f robots per covered target on %d validation trials", name, cap, trials)
        return self.spread_cap

    # -- status, checkpoints, report --------------------------------------------------------------------------------

    def _publish_status(self) -> None:
        figures = self.intake.figures()
        status = LearnerStatus.of(figures, self.state, self.members, self.evaluator, self.fitter.fits, self.elapsed())
        me = self.config.learner_id
        msg = Status(sender=me, role="learner", wall_time=time.time(), counters=status.to_counters())
        self.transport.publish(self.transport.keys.status(me), msg)
        log.debug("status %s", status)
        self.watch.status(status, actors=self.members.seen(), lag=self.state.lag(figures.latest_version))

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
                **({} if self.keeper is None else self.keeper.to_meta()),
                **({} if self.early is None else {"early": self.early.to_meta()}),
                "window_at": self._window_at,
                "draws": {
                    "draw": self._draw,
                    "window_scored": self._window_scored,
                    "scored": self.draws,
                    "best": None if self._drawn is None else self._drawn.to_meta(),
                },
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
            if self.keeper is not None:
                self.keeper.restore(meta, self._kept_file(BEST_POLICY) if meta.get("kept") else None)
            early = meta.get("early")
            if self.early is not None and isinstance(early, dict):
                self.early.restore(early, self._kept_file(EARLY_POLICY) if early.get("kept") else None)
            # A checkpoint written before the draws names the window's start first_policy_at and holds no draws.
            window = meta.get("window_at", meta.get("first_policy_at"))
            self._window_at = None if window is None else float(window)
            self._restore_draws(meta.get("draws", {"draw": 0, "window_scored": False, "scored": [], "best": None}))
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

    def _restore_draws(self, meta: dict[str, Any]) -> None:
        self._draw = int(meta["draw"])
        self._window_scored = bool(meta["window_scored"])
        self.draws = list(meta["scored"])
        best = meta["best"]
        policy = None if best is None else self._kept_file(DRAWN_POLICY)
        self._drawn = None if best is None or policy is None else _Scored.from_meta(best, policy)

    def _kept_file(self, name: str) -> Policy | None:
        try:
            return load_policy(self.run_dir / name)[0]
        except PolicyFileError as exc:
            log.warning("--resume: the kept policy %s is lost (%s); the next one scored is kept instead", name, exc)
            return None

    def _finish(self) -> LearnerReport:
        self.fitter.join()  # a fit under way finishes, so its work is in the final policy
        final = None
        if self.state.fitted:
            self._broadcast()
            last = self.state.policy()
            assert last is not None
            if self.keeper is not None and self.keeper.scores:  # else the last is the only candidate: not scored
                self._offer(last)
            self._select()
            policy = self._chosen()
            assert policy is not None
            final = self.evaluator.final(policy)
            self.watch.final(policy, final, self.config.final_eval_trials, self.evaluator.comparison())
            log.info("final policy version %d: %.2f%% of targets observed", policy.version, final)
        report = self._report(final, self.checkpoint(), self.elapsed())
        write_atomic(self.run_dir / "report.json", json.dumps(report.to_dict(), indent=2).encode())
        return report

    def saved_report(self) -> LearnerReport:
        """The report of what a resumed learner's checkpoint holds, with its policy file, without training or
        scoring: for a launcher whose learner was killed before it wrote its own report (``report.json`` is left to
        the launcher)."""
        return self._report(None, self.checkpointer.path, self._elapsed_before)

    def _report(self, final: float | None, checkpoint: Path, elapsed: float) -> LearnerReport:
        policy = self._chosen()
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
            keeper=self.keeper,
            margin=self.margin,
            policy=policy,
            candidates=self.candidates,
            draws=self.draws,
            spread_cap=None
            if self.config.spread_cap is None or self.spread_cap is None
            else (self.config.spread_cap, self.spread_cap),
        )


@dataclasses.dataclass(frozen=True, slots=True)
class _Scored:
    """A candidate for the saved policy as scored on the margin's validation trials."""

    source: str
    """``kept`` or ``early``."""
    policy: Policy
    at: float
    """When it was kept (the run clock)."""
    coverage: float
    """Its coverage on the margin's validation trials, read with ``margin`` when one was chosen."""
    margin: MarginChoice | None
    spread: float | None
    """Its robots per covered target on the same trials (None: scored before they were recorded)."""
    draw: int | None = None
    """An early candidate's draw."""

    def rank(self, cap: float | None) -> tuple[bool, float]:
        return rank(self.coverage, self.spread, cap)

    def figures(self, chosen: bool) -> dict[str, Any]:
        return {"source": self.source, **self.summary(), "chosen": chosen}

    def summary(self) -> dict[str, Any]:
        return {
            **({} if self.draw is None else {"draw": self.draw}),
            "version": self.policy.version,
            "at_s": round(self.at, 2),
            "validation_coverage": round(self.coverage, 3),
            **({} if self.spread is None else {"robots_per_covered_target": round(self.spread, 4)}),
            **({} if self.margin is None else {"margin": self.margin.margin}),
        }

    def to_meta(self) -> dict[str, Any]:
        """What a checkpoint holds of it besides the policy (in its own file)."""
        m = self.margin
        choice = (
            None
            if m is None
            else {
                "margin": m.margin,
                "scores": list(m.scores.items()),
                "spreads": list(m.spreads.items()),
                "trials": m.trials,
                "seed": m.seed,
            }
        )
        return {
            "source": self.source,
            "at": self.at,
            "coverage": self.coverage,
            "spread": self.spread,
            "margin": choice,
            "draw": self.draw,
        }

    @classmethod
    def from_meta(cls, meta: dict[str, Any], policy: Policy) -> _Scored:
        m = meta["margin"]
        choice = None
        if m is not None:
            scores = {float(k): float(v) for k, v in m["scores"]}
            # A checkpoint written before the spreads were recorded holds none.
            spreads = {float(k): float(v) for k, v in m.get("spreads", [])}
            choice = MarginChoice(float(m["margin"]), scores, int(m["trials"]), int(m["seed"]), spreads)
        draw, spread = meta["draw"], meta.get("spread")
        return cls(
            str(meta["source"]),
            policy,
            float(meta["at"]),
            float(meta["coverage"]),
            choice,
            None if spread is None else float(spread),
            None if draw is None else int(draw),
        )


class _Checkpoints:
    """Checkpoints every ``interval`` seconds on a thread of their own, the first at once. Acknowledgements follow
    checkpoints, so an evaluation (seconds of trials on the loop's thread) must not hold them up: meanwhile every
    actor's outbox would fill with unacknowledged experience (≈ 40 MB a second each). A checkpoint that fails ends
    the thread and is raised on the loop's thread when the block ends; ``failure`` tells the loop to stop."""

    def __init__(self, checkpoint: Callable[[], object], interval: float) -> None:
        self._checkpoint = checkpoint
        self._interval = interval
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="checkpoints", daemon=True)
        self.failure: Exception | None = None

    def __enter__(self) -> _Checkpoints:
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self._done.set()
        self._thread.join()
        if self.failure is not None and exc_type is None:
            raise self.failure

    def _loop(self) -> None:
        try:
            while True:
                self._checkpoint()
                if self._done.wait(self._interval):
                    return
        except Exception as exc:  # raised again on the loop's thread by __exit__
            self.failure = exc


def _prototypes(policy: Policy) -> float:
    return round(float(policy.discretization.sizes().mean()), 1)
