"""When ENNC-QL phase 1 runs: in the background, once ``min_tuples`` are stored, then again, warm-started, each time
the tuples received have grown ``refit_growth`` times since the last fit took its data; or afresh, on the first
fit's tuples, when the learner asks for another draw (``draws``).

Usage (``poll`` and ``draw`` from the learner's loop; ``on_fitted`` runs on the fit's own thread)::

    fitter = Fitter(config, on_fitted=adopt, exploration=run_dir / EXPLORATION)
    fitter.poll(intake, state.discretization)      # starts a fit when one is due and none is running
    fitter.draw(1)                                 # phase 1 afresh on the first fit's tuples: adopt(disc, fresh=True)
    fitter.join()                                  # at the end: a fit under way finishes (a draw is stopped)
    fitter.fits, fitter.fit_s                      # fits done, seconds the last one took
    meta = fitter.to_meta(); fitter.restore(meta)  # for a checkpoint
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.discretization import Discretization
from algorithm.files import save_npz_atomic
from algorithm.phase1 import phase1
from algorithm.transitions import Transitions
from learner.config import LearnerConfig
from learner.intake import ExperienceIntake
from protocol import N_ACTIONS
from sim import scenario

log = logging.getLogger(__name__)


EXPLORATION = "exploration.npz"
"""The run folder's copy of the first fit's tuples, which every later draw fits on (``draws`` > 1)."""


class _DrawStopped(Exception):
    """Raised inside phase 1 on a draw's thread once the learner stops."""


class Fitter:
    def __init__(
        self,
        config: LearnerConfig,
        on_fitted: Callable[[Discretization, bool], None],
        exploration: Path | None = None,
    ) -> None:
        self.config = config
        self.on_fitted = on_fitted
        """Called with each fit's discretization and whether it is a draw (its tables start afresh)."""
        self.exploration = exploration
        """Where the first fit's tuples are kept for the draws (None: not kept)."""
        self.fits = 0
        self.fit_s = 0.0
        """Seconds the last fit took (0 before the first)."""
        self._fitted_at = 0  # tuples received when the last fit took its data
        self._rng = np.random.default_rng(config.seed)
        self._thread: threading.Thread | None = None
        self._drawing = False
        self._stop_draw = threading.Event()
        """Set at the end: a draw under way stops at its next action's fit."""
        self._tuples: Transitions | None = None
        self._lost = False
        """The first fit's tuples could not be read back: no more draws (warned once)."""

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def poll(self, intake: ExperienceIntake, warm_start: Discretization | None) -> None:
        """Start phase 1 when due; the loop keeps storing, acking and broadcasting meanwhile."""
        if self.busy:
            return
        c = self.config
        if warm_start is None:
            due = len(intake) >= c.min_tuples
        else:
            due = c.refit_growth > 0 and intake.tuples_received >= c.refit_growth * self._fitted_at
        if due:
            self._start(lambda: self._snapshot(intake, keep=warm_start is None), warm_start, draw=None)

    def _snapshot(self, intake: ExperienceIntake, keep: bool) -> Transitions:
        data, self._fitted_at = intake.snapshot_for_fit()
        if keep and self.exploration is not None:  # the first fit's: every draw fits on them
            save_npz_atomic(self.exploration, dataclasses.asdict(data))
            self._tuples = data
        return data

    def draw(self, index: int) -> bool:
        """Start draw ``index``: phase 1 afresh (its own seed, no warm start) on the first fit's tuples. False when a
        fit is under way or those tuples are lost."""
        if self.busy or self._lost:
            return False
        data = self._tuples if self._tuples is not None else self._load()
        if data is None:
            self._lost = True
            return False
        self._tuples = data
        self._start(lambda: data, None, draw=index)
        return True

    def _start(self, take: Callable[[], Transitions], warm_start: Discretization | None, draw: int | None) -> None:
        """A fit on the tuples ``take`` gives, on a thread of its own; ``draw``: the draw's index (None: no draw)."""
        if draw is None:
            seed = int(self._rng.integers(2**31))
        else:  # a resumed learner draws the same draw with the same seed
            seed = int(np.random.default_rng([self.config.seed, draw]).integers(2**31))
        self._drawing = draw is not None
        self._stop_draw.clear()
        self._thread = threading.Thread(target=self._fit, args=(take, warm_start, seed), name="phase1", daemon=True)
        self._thread.start()

    def _fit(self, take: Callable[[], Transitions], warm_start: Discretization | None, seed: int) -> None:
        data = take()
        kind = "a draw" if self._drawing else "first fit" if warm_start is None else "warm start"
        log.info("phase 1 on %d tuples (%s)", len(data), kind)
        began = time.monotonic()
        cfg = scenario(self.config.scenario)
        lost = self.config.resolved.featurizer.sees_none(cfg, data.next_state)
        try:
            disc = phase1(
                data,
                N_ACTIONS,
                self.config.phase1,
                seed=seed,
                warm_start=warm_start,
                progress=self._check_stop,
                lost=lost,
                lost_reward=cfg.lost_reward,
            ).discretization
        except _DrawStopped:
            log.info("the draw under way stopped after %.1f s of phase 1", time.monotonic() - began)
            return
        self.fits += 1
        self.fit_s = time.monotonic() - began
        log.info(
            "phase 1 done in %.1f s: %.1f prototypes per action (%d cells)",
            self.fit_s,
            disc.sizes().mean(),
            disc.size,
        )
        self.on_fitted(disc, self._drawing)

    def _check_stop(self, iteration: int, action: int) -> None:
        if self._drawing and self._stop_draw.is_set():
            raise _DrawStopped

    def _load(self) -> Transitions | None:
        if self.exploration is None or not self.exploration.exists():
            log.warning("no more draws: the first fit's tuples are not kept (%s)", self.exploration)
            return None
        try:
            with np.load(self.exploration, allow_pickle=False) as data:
                return Transitions(**{f.name: data[f.name] for f in dataclasses.fields(Transitions)})
        except (OSError, ValueError, KeyError) as exc:
            log.warning("no more draws: the first fit's tuples %s are unreadable (%s)", self.exploration, exc)
            return None

    def join(self) -> None:
        """Wait for a fit under way; a draw's is stopped first (its tables would start afresh with no time left to
        learn), so that it gives the cores back to the end's scoring within one action's fit."""
        if self._thread is None:
            return
        if self._drawing and self._thread.is_alive():
            log.info("a draw under way is stopped")
            self._stop_draw.set()
        self._thread.join()

    def to_meta(self) -> dict[str, Any]:
        return {"fits": self.fits, "fitted_at": self._fitted_at, "fit_s": round(self.fit_s, 2)}

    def restore(self, meta: dict[str, Any]) -> None:
        self.fits = int(meta["fits"])
        self._fitted_at = int(meta["fitted_at"])
        self.fit_s = float(meta.get("fit_s", 0.0))  # none in checkpoints written before the draws
