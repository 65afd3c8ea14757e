"""When ENNC-QL phase 1 runs: in the background, once ``min_tuples`` are stored, then again, warm-started, each time
the tuples received have grown ``refit_growth`` times since the last fit took its data. A warm start carries the
tables over (each new cell inherits the value of the old cell nearest it, ``learner.policy_state``): no fit replaces
the tables the actors' acknowledged increments went into.

Usage (``poll`` from the learner's loop; ``on_fitted`` runs on the fit's own thread)::

    fitter = Fitter(config, on_fitted=adopt)
    fitter.poll(intake, state.discretization)      # starts a fit when one is due and none is running
    fitter.join()                                  # at the end: a fit under way finishes
    fitter.fits, fitter.fit_s                      # fits done, seconds the last one took
    meta = fitter.to_meta(); fitter.restore(meta)  # for a checkpoint
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from algorithm.discretization import Discretization
from algorithm.phase1 import phase1
from algorithm.transitions import Transitions
from learner.config import LearnerConfig
from learner.intake import ExperienceIntake
from protocol import N_ACTIONS
from sim import scenario

log = logging.getLogger(__name__)


class Fitter:
    def __init__(self, config: LearnerConfig, on_fitted: Callable[[Discretization], None]) -> None:
        self.config = config
        self.on_fitted = on_fitted
        """Called with each fit's discretization, on the fit's thread."""
        self.fits = 0
        self.fit_s = 0.0
        """Seconds the last fit took (0 before the first)."""
        self._fitted_at = 0  # tuples received when the last fit took its data
        self._rng = np.random.default_rng(config.seed)
        self._thread: threading.Thread | None = None

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
            seed = int(self._rng.integers(2**31))
            args = (intake, warm_start, seed)
            self._thread = threading.Thread(target=self._fit, args=args, name="phase1", daemon=True)
            self._thread.start()

    def _fit(self, intake: ExperienceIntake, warm_start: Discretization | None, seed: int) -> None:
        data: Transitions
        data, self._fitted_at = intake.snapshot_for_fit()
        log.info("phase 1 on %d tuples (%s)", len(data), "first fit" if warm_start is None else "warm start")
        began = time.monotonic()
        cfg = scenario(self.config.scenario)
        lost = self.config.resolved.featurizer.sees_none(cfg, data.next_state)
        disc = phase1(
            data,
            N_ACTIONS,
            self.config.phase1,
            seed=seed,
            warm_start=warm_start,
            lost=lost,
            lost_reward=cfg.lost_reward,
        ).discretization
        self.fits += 1
        self.fit_s = time.monotonic() - began
        log.info(
            "phase 1 done in %.1f s: %.1f prototypes per action (%d cells)",
            self.fit_s,
            disc.sizes().mean(),
            disc.size,
        )
        self.on_fitted(disc)

    def join(self) -> None:
        """Wait for a fit under way, so its work is in the final policy."""
        if self._thread is not None:
            self._thread.join()

    def to_meta(self) -> dict[str, Any]:
        return {"fits": self.fits, "fitted_at": self._fitted_at, "fit_s": round(self.fit_s, 2)}

    def restore(self, meta: dict[str, Any]) -> None:
        self.fits = int(meta["fits"])
        self._fitted_at = int(meta["fitted_at"])
        self.fit_s = float(meta.get("fit_s", 0.0))
