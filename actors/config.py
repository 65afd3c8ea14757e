"""The actor process's configuration: every default of ``ennc-ql actor`` is written here, once.

The command's flags are generated from these fields (their docstrings are the ``--help`` text), ``--config FILE``
reads the same fields from TOML, and ``ennc-ql up`` builds one of these instead of a command line.
"""

from __future__ import annotations

import os
import re
import socket
from dataclasses import dataclass, field

from algorithm.agent import Phase2Config
from algorithm.checks import require_at_least, require_at_most, require_id, require_known, require_positive
from sim import SCENARIOS
from sim.formulation import DEFAULT_FORMULATION, Formulation, resolve_formulation
from sim.world import MAX_ARENAS


def parse_robots(text: str) -> tuple[int, ...]:
    """Robot ids from ranges and lists.

    >>> parse_robots("0-4,7")
    (0, 1, 2, 3, 4, 7)
    """
    robots: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, _, hi = part.partition("-")
        try:
            first, last = int(lo), int(hi or lo)
        except ValueError:
            raise ValueError(f"bad robot range {part!r} (expected e.g. 0-4,7)") from None
        if first < 0 or last < first:
            raise ValueError(f"bad robot range {part!r}")
        robots.extend(range(first, last + 1))
    if not robots:
        raise ValueError("no robots given")
    return tuple(sorted(set(robots)))


def resolve_actor_id(text: str) -> str:
    """``auto`` becomes ``actor-<hostname>-<pid>``: replicas started from one command line (compose
    ``deploy.replicas``) need distinct ids, and a container's hostname is unique per replica, a pid per process."""
    if text == "auto":
        host = re.sub(r"[^A-Za-z0-9_.-]", "-", socket.gethostname())[:40]
        return f"actor-{host}-{os.getpid()}"
    return text


@dataclass(frozen=True, slots=True)
class ActorConfig:
    actor_id: str = field(default="actor-0", metadata={"parse": resolve_actor_id})
    """Actor id, unique in the run (letters, digits, '_', '.', '-'); 'auto': from the hostname and pid."""
    scenario: str = "cmommt-v1"
    """Scenario the actor simulates."""
    formulation: str = DEFAULT_FORMULATION
    """State, reward and action set of the learning robots, by name (see docs/concepts/learning.md; paper is
    the paper's). The learner's must be the same: its experience is the actors'."""
    featurizer: str | None = None
    """State definition instead of the formulation's (none: the formulation's)."""
    reward: str | None = None
    """Reward instead of the formulation's (none: the formulation's; paper: the state's own, observed for local2d and
    Eq. 2 otherwise)."""
    trial_rules: str | None = None
    """Learning-trial rules instead of the formulation's (none: the formulation's; paper: a learner that loses every
    target ends its trial and the time-out is terminal; the others go beyond the paper, see
    docs/concepts/simulator.md). The learner never reads them."""
    learning_steps: int | None = None
    """Steps of each learning trial instead of the scenario's (None: the scenario's) [beyond the paper; the
    learner's test trials keep theirs; screened in docs/notebook.md, "2026-12-04: the law's move as one of the
    learned choices"]."""
    learn: tuple[int, ...] | None = field(default=None, metadata={"parse": parse_robots})
    """Robot ids whose tables this actor learns (and whose tuples it streams), e.g. 0-4,7; None = every robot."""
    arenas: int = 256
    """Arenas simulated side by side, at most 100 000 (sim.world.MAX_ARENAS); every arena holds all m robots."""
    seed: int = 0
    """Run seed; the actor's random stream is derived from (seed, actor id), so no two actors share one."""
    batch_size: int = 16384
    """Tuples per experience message."""
    outbox_limit: int = 32
    """Unacknowledged messages kept for re-sending; when full the actor waits for acks. This bounds the actor's
    in-flight experience: 32 messages of 16 384 tuples of 11-number states ≈ 50 MB, so an actor stays under 300 MB
    even when a busy learner acknowledges late (docs/performance.md, "Memory of the processes")."""
    resend_after: float = 10.0
    """Seconds without an ack after which a message is sent again."""
    flush_timeout: float = 10.0
    """On stopping, seconds to wait for the learner to acknowledge the outbox (it acks after each checkpoint)."""
    duration: float | None = None
    """Stop after this many seconds (None: run until stopped)."""
    max_tuples_per_s: float | None = None
    """Pace the actor to at most this many tuples per second, resting between trials (None: as fast as it can); for
    an actor that shares its cores with other work."""
    status_interval: float = 2.0
    """Seconds between status messages."""
    phase2: Phase2Config = field(default_factory=lambda: Phase2Config(alpha_floor=0.01))
    """On-line Q-learning of the robots this actor learns; each cell's step size decays from alpha to 0.01 as it is
    visited [beyond the paper: the actors of a run see hundreds of millions of tuples]."""
    draw_every: int = 10
    """With monitoring on, every this many trials arena 0 is drawn at each step of the trial."""
    resolved: Formulation = field(init=False, repr=False, compare=False)
    """The formulation this actor runs: ``formulation`` with the explicit fields over it (resolved here, once)."""

    def __post_init__(self) -> None:
        require_id("actor_id", self.actor_id)
        require_known("scenario", self.scenario, SCENARIOS)
        resolved = resolve_formulation(
            self.formulation, featurizer=self.featurizer, reward=self.reward, trial_rules=self.trial_rules
        )
        object.__setattr__(self, "resolved", resolved)
        require_at_least(
            1,
            arenas=self.arenas,
            batch_size=self.batch_size,
            outbox_limit=self.outbox_limit,
            draw_every=self.draw_every,
        )
        require_at_most(MAX_ARENAS, arenas=self.arenas)
        require_positive(
            learning_steps=self.learning_steps,
            resend_after=self.resend_after,
            status_interval=self.status_interval,
            duration=self.duration,
            max_tuples_per_s=self.max_tuples_per_s,
        )
        require_at_least(0, seed=self.seed)
        if self.flush_timeout < 0:
            raise ValueError(f"flush_timeout must be 0 or more, got {self.flush_timeout}")
        n_robots = SCENARIOS[self.scenario].n_robots
        if self.learn is not None and (not self.learn or max(self.learn) >= n_robots or min(self.learn) < 0):
            raise ValueError(
                f"learn: robots {self.learn} do not all exist: the scenario has {n_robots} (0-{n_robots - 1})"
            )

    def learning_robots(self) -> tuple[int, ...]:
        return self.learn if self.learn is not None else tuple(range(SCENARIOS[self.scenario].n_robots))
