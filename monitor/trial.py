"""Recording a test trial for replay (``ennc-ql eval``): the arena at every step and the per-step coverage.

Usage::

    from monitor import Sink, open_monitor
    from monitor.trial import record_trial
    with open_monitor(Sink("save", "trial.rrd"), process="eval") as monitor:
        monitor.send_blueprint(eval_trial=True)
        coverage = record_trial(scenario(), HAND_MADE["a-cmommt"], monitor, seed=0, steps=1000)

To record trial k of an evaluation exactly as it was scored, pass ``trial_hook(monitor, cfg, arena=k)`` as the
``on_step`` of :func:`sim.evaluate` instead.
"""

from __future__ import annotations

import time

import numpy as np

from monitor import paths
from monitor.interface import Monitor
from sim.config import ScenarioConfig
from sim.controllers import Controller
from sim.features import coverage
from sim.rollout import StepHook, evaluate
from sim.world import Observation, WorldState


def trial_hook(monitor: Monitor, cfg: ScenarioConfig, *, arena: int = 0) -> StepHook:
    """An ``on_step`` hook for :func:`sim.evaluate` that logs arena ``arena`` of the batch at every step.

    Logs the arena under ``eval/arena`` and its coverage (%) at ``eval/coverage``, both on ``sim_step`` = the
    world's step count (1 for the state after the first step).
    """

    def on_step(world: WorldState, obs: Observation) -> None:
        monitor.arena(
            paths.EVAL_ARENA,
            world.robot_pos[arena],
            world.target_pos[arena],
            sensing_range=cfg.sensing_range,
            arena_radius=cfg.arena_radius,
            sim_step=world.t,
        )
        monitor.scalars(paths.EVAL, {paths.EVAL_COVERAGE_NAME: float(coverage(cfg, obs)[arena])}, sim_step=world.t)

    return on_step


def record_trial(
    cfg: ScenarioConfig, controller: Controller, monitor: Monitor, *, seed: int = 0, steps: int | None = None
) -> float:
    """Run one test trial (one arena, seeded) of ``steps`` steps (default ``cfg.test_steps``), logging every step.

    Returns the trial's metric A (%). The trial is the one :func:`sim.evaluate` runs with ``trials=1`` and the same
    seed, so its score is reproducible from ``(cfg, controller, seed, steps)``.
    """
    result = evaluate(cfg, controller, trials=1, steps=steps, seed=seed, on_step=trial_hook(monitor, cfg))
    return float(result.coverage_per_trial[0])


class TrialWatch:
    """The step hook of one learning trial of an actor under monitoring: arena 0 drawn at each step of a sampled
    trial, and the trial's coverage over every arena; ``report`` logs the trial's figures on the actor's
    ``sim_step`` timeline.

    Usage (an actor's loop)::

        watch = TrialWatch(monitor, cfg, "actor-0", first_step=trial * cfg.learning_steps, draw=trial % 10 == 0)
        batch = experience_slice.run_trial(agent, update=True, on_step=watch)
        watch.report(batch.reward[batch.done], tuples_sent=..., policy_version=...)
    """

    def __init__(
        self, monitor: Monitor, cfg: ScenarioConfig, actor_id: str, first_step: int, draw: bool, start: float
    ) -> None:
        self.monitor = monitor
        self.cfg = cfg
        self.actor_id = actor_id
        self.origin = paths.actor_arena(actor_id)
        self.step = first_step
        self.draw = draw
        self.start = start
        self.steps = 0
        self.covered = 0.0

    def __call__(self, world: WorldState, obs: Observation) -> None:
        self.step += 1
        self.steps += 1
        self.covered += float(obs.covered.mean())
        if self.draw:
            self.monitor.arena(
                self.origin,
                world.robot_pos[0],
                world.target_pos[0],
                sensing_range=self.cfg.sensing_range,
                arena_radius=self.cfg.arena_radius,
                sim_step=self.step,
            )

    def report(self, final_rewards: np.ndarray, tuples_sent: float, policy_version: int) -> None:
        """``final_rewards``: the rewards of the trial's terminal tuples (delayed rewards, Eq. 2)."""
        self.monitor.actor_metrics(
            self.actor_id,
            sim_step=self.step,
            coverage=100.0 * self.covered / max(self.steps * self.cfg.n_targets, 1),
            mean_reward=float(final_rewards.mean()) if final_rewards.size else None,
            tuples_per_s=tuples_sent / max(time.monotonic() - self.start, 1e-9),
            policy_version=policy_version,
        )
