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
