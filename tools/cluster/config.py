"""The configuration of a local run: one learner and N actors, every setting in :class:`UpConfig`, with ``up``'s own
presets named once (:data:`UP_PRESETS`) and each child's resolved configuration written into the run folder::

    config = load_config(UpConfig, defaults=UP_PRESETS)       # or from a run's up.toml, flags over it
    learner, actors = child_configs(config)                   # what each process is started with
    write_configs(config, learner, actors, run_dir)           # up.toml, learner.toml, actor-<i>.toml
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from actors.config import ActorConfig
from algorithm.checks import require_at_least, require_known, require_positive
from learner.config import LearnerConfig
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS
from tools.config import dump_config

FORMULATION_PARTS = ("featurizer", "reward", "act_every")
"""Fields of the learner's and the actors' configurations that override their formulation's parts: ``up`` gives
every process the one formulation it names instead."""


@dataclass(frozen=True, slots=True)
class UpConfig:
    actors: int = 2
    """Actor processes (each learns every robot's table: option 2)."""
    duration: float = 120.0
    """Seconds of training: as long as more experience adds to the policy; phase 2's values settle within two
    minutes and later tables score no better (docs/results.md, "How learning grows with training time")."""
    seed: int = 0
    """Run seed, given to the learner and to every actor (each derives its own stream from it and its id)."""
    formulation: str = DEFAULT_FORMULATION
    """State, reward, action set and test-time decision period of every process, by name: the
    default is make run's (docs/concepts/learning.md says why), paper the paper's. The actors' learning-trial
    rules are the formulation's unless --actor-trial-rules names others."""
    max_restarts: int = 3
    """Times in a row a child that dies (the learner, an actor, the router) is started again, after 1, 2, 4 ... s,
    before the run gives up on it (the learner resumes from its checkpoint; one that ran a minute starts a new
    row); a learner given up ends the run."""
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    """The learner process."""
    actor: ActorConfig = field(default_factory=ActorConfig)
    """Every actor process (ids actor-0, actor-1, ...)."""

    def __post_init__(self) -> None:
        require_at_least(1, actors=self.actors)
        require_at_least(0, seed=self.seed)
        require_at_least(0, max_restarts=self.max_restarts)
        require_positive(duration=self.duration)
        require_known("formulation", self.formulation, FORMULATIONS)
        parts = [
            f"{role}.{name}"
            for role, process in (("learner", self.learner), ("actor", self.actor))
            for name in FORMULATION_PARTS
            if getattr(process, name, None) is not None
        ]
        if parts:
            raise ValueError(f"{', '.join(parts)}: up gives every process the formulation it names (--formulation)")
        self._check_set_by_up()
        # The learner's and the actors' own formulation is up's, so that up.toml says one thing once.
        for role in ("learner", "actor"):
            object.__setattr__(self, role, dataclasses.replace(getattr(self, role), formulation=self.formulation))

    def _check_set_by_up(self) -> None:
        """A field of the learner's or the actors' that up sets itself, given otherwise in a file, is an error: up
        would override it without a word. Its default (what up.toml files of earlier versions hold) is fine."""
        ours = {"duration": self.duration, "seed": self.seed, "formulation": self.formulation, "actor_id": None}
        source = {"duration": "duration", "seed": "seed", "formulation": "formulation", "actor_id": "actors"}
        for role in ("learner", "actor"):
            process = getattr(self, role)
            for f in dataclasses.fields(process):
                if f"{role}.{f.name}" not in SET_BY_UP or f.name not in ours:
                    continue
                value = getattr(process, f.name)
                mine = None if (role, f.name) == ("actor", "duration") else ours[f.name]
                if value != f.default and value != mine:
                    raise ValueError(
                        f"{role}.{f.name} = {value!r}: up sets every {role}'s {f.name} itself, from "
                        f"{source[f.name]}; leave {role}.{f.name} out (give {source[f.name]} instead)"
                    )


UP_PRESETS: dict[str, Any] = {
    # A 400 000-tuple store holds under a second of two actors' experience (~530 k tuples/s) and keeps the learner's
    # RSS modest.
    "learner.store_capacity": 400_000,
    # Evaluations (10 trials, under a second) cost CPU the actors share: every 10 s gives a 2-minute run a learning
    # curve of about ten points.
    "learner.eval_interval": 10.0,
    # Multi-threaded torch stalls on cores the actors keep busy; one thread is as fast there.
    "learner.threads": 1,
    # Two actors x 500 arenas saturate the 2-core machine without starving the learner.
    "actor.arenas": 500,
}
"""What ``ennc-ql up`` sets differently from the processes' own defaults, named once."""

SET_BY_UP = (
    "learner.duration",
    "learner.seed",
    "learner.formulation",
    *(f"learner.{name}" for name in FORMULATION_PARTS),
    "actor.actor_id",
    "actor.seed",
    "actor.duration",
    "actor.formulation",
    "actor.featurizer",
    "actor.reward",
)
"""Fields ``up`` fills in itself from its own settings (no flags for them)."""


def child_configs(config: UpConfig) -> tuple[LearnerConfig, list[ActorConfig]]:
    learner = dataclasses.replace(config.learner, duration=config.duration, seed=config.seed)
    actors = [
        dataclasses.replace(config.actor, actor_id=f"actor-{i}", seed=config.seed, duration=None)
        for i in range(config.actors)
    ]
    return learner, actors


def write_configs(config: UpConfig, learner: LearnerConfig, actors: list[ActorConfig], run_dir: Path) -> None:
    """Every process's resolved configuration in the run folder: the run can be repeated exactly from them."""
    (run_dir / "up.toml").write_text(dump_config(config, exclude=SET_BY_UP))
    (run_dir / "learner.toml").write_text(dump_config(learner))
    for actor in actors:
        (run_dir / f"{actor.actor_id}.toml").write_text(dump_config(actor))
