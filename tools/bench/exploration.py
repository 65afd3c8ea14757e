"""Random-exploration experience of CMOMMT, the data the learning-core benchmarks fit on."""

from __future__ import annotations

import numpy as np

from algorithm.transitions import Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from sim import FORMULATIONS, scenario


def cmommt_experience(tuples: int, seed: int = 0, action: int | None = None) -> Transitions:
    """``tuples`` collaborative (6-D) tuples from random-exploration learning trials (only ``action``'s, if given)."""
    cfg = scenario()
    explorer = ExperienceSlice(cfg, SliceConfig(FORMULATIONS["paper"], n_arenas=1000), seed)
    parts: list[Transitions] = []
    collected = 0
    while collected < tuples:
        batch = explorer.run_trial()
        if action is not None:
            batch = batch.take(np.nonzero(batch.action == action)[0])
        parts.append(batch)
        collected += len(batch)
    data = Transitions.concat(parts)
    return data.take(np.arange(tuples))
