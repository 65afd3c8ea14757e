"""``ennc-ql bench actor``: an actor's phase-2 slice (ε-greedy trials on per-robot tables, its experience messages
built) against the bare simulator, measured in the same run::

    bench_actor(seconds=2.0)["ratio"]              # an actor's phase-2 slice / the bare simulator
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from algorithm.agent import Phase2Config, TabularAgent
from algorithm.phase1 import CMOMMT_PHASE1, phase1
from algorithm.policy import Policy
from algorithm.transitions import Batcher, Transitions
from algorithm.trials import ExperienceSlice, SliceConfig
from algorithm.wire import experience_batches
from protocol import Header
from sim import N_ACTIONS, ScenarioConfig, scenario
from sim.formulation import FORMULATIONS, Formulation, default_formulation
from tools.bench.sim import sim_rate
from tools.progress import ProgressBar

ACTOR_TARGET_RATIO = 0.25
"""An actor's phase-2 slice must run at this fraction of the bare simulator's robot-steps/s (actor throughput issue)."""


def bench_policy(cfg: ScenarioConfig, arenas: int = 500, explore_trials: int = 2, seed: int = 0) -> Policy:
    """A realistic phase-2 policy: ENNC-QL phase 1 (option 2, the learner's defaults) on random-exploration tuples.

    Two trials in 500 arenas give ≈ 180 k tuples and ≈ 150–300 prototypes per action, the size a ``make run``
    policy has (docs/performance.md), so the nearest-prototype search costs what it costs in a real run.
    """
    paper = FORMULATIONS["paper"]
    explorer = ExperienceSlice(cfg, SliceConfig(paper, n_arenas=arenas), seed)
    data = Transitions.concat([explorer.run_trial() for _ in range(explore_trials)])
    disc = phase1(data, N_ACTIONS, CMOMMT_PHASE1, seed=seed).discretization
    return Policy(
        formulation=paper,
        discretization=disc,
        tables=np.tile(disc.labels, (cfg.n_robots, 1)),
        robot_table=np.arange(cfg.n_robots),
        action_steps=cfg.action_steps,
        method="ennc-ql-collab-option2",
    )


def _as_actor_runs(policy: Policy, formulation: Formulation | None) -> Policy:
    """``policy`` under the formulation an actor would run it in (:func:`bench_actor`)."""
    if formulation is None:
        default = default_formulation()
        formulation = default if default.names == policy.formulation.names else policy.formulation
    elif formulation.names != policy.formulation.names:
        raise ValueError(
            f"the formulation's state, reward and moves {formulation.names} are not the policy's "
            f"{policy.formulation.names}"
        )
    return dataclasses.replace(policy, formulation=formulation)


def _actor_trials(
    cfg: ScenarioConfig, agent: TabularAgent, arenas: int, seconds: float, batch_size: int, seed: int
) -> dict[str, float]:
    """Phase-2 learning trials as an actor runs them (every robot learns), with its experience messages built, in
    the formulation the agent's policy was learned in.

    Returns the robot-steps, tuples and the seconds spent in the slice and in building the messages.
    """
    policy = agent.template
    formulation = policy.formulation
    parts = SliceConfig(formulation, n_arenas=arenas)
    experience = ExperienceSlice(cfg, parts, seed)
    counts = {"tuples": 0, "messages": 0}
    message_s = 0.0

    def send(tuples: Transitions) -> None:
        nonlocal message_s
        built = time.perf_counter()
        for build in experience_batches(tuples, batch_size, formulation):
            build(Header(actor_id="bench", incarnation=1, seq=counts["messages"], policy_version=1))
            counts["messages"] += 1
        counts["tuples"] += len(tuples)
        message_s += time.perf_counter() - built

    batcher = Batcher(batch_size, send)
    steps = 0
    trials_s = 0.0
    while steps == 0 or trials_s < seconds:
        start = time.perf_counter()
        experience.stream_trial(batcher.add, agent, update=True)
        batcher.flush()
        trials_s += time.perf_counter() - start
        steps += arenas * cfg.n_robots * cfg.learning_steps
    # The messages are built inside the trials, as the actor sends them while each trial runs.
    return {"steps": steps, "tuples": counts["tuples"], "slice_s": trials_s - message_s, "message_s": message_s}


def bench_actor(
    scenario_name: str = "cmommt-v1",
    arenas: int = 500,
    seconds: float = 1.5,
    rounds: int = 3,
    policy: Policy | None = None,
    batch_size: int = 16384,
    formulation: Formulation | None = None,
) -> dict[str, Any]:
    """An actor's phase-2 slice against the bare simulator, measured in the same run.

    ``rounds`` alternations of ``seconds`` of the simulator (random controller, the same ``arenas``) and of at least
    ``seconds`` (whole trials) of the actor's learning trials (ε-greedy on per-robot tables, on-line Eq. 1,
    experience messages built as the actor builds them), so that a machine whose load changes meanwhile slows both
    alike. ``policy`` None learns a realistic one (:func:`bench_policy`). ``formulation`` is the one the actor runs
    (its trial rules, e.g. a guide, are not in a policy file; as an actor does, its policy takes it): by default the
    run's default formulation when the policy's state, reward and moves are its own, else the policy's parts under
    the paper's trial rules. ValueError if it names other parts than the policy's.
    """
    cfg = scenario(scenario_name)
    with ProgressBar("bench actor", total=2 * rounds + 1, unit="phases") as bar:
        bar.show(status="learning a policy (exploration + phase 1)" if policy is None else "policy given")
        policy = _as_actor_runs(policy or bench_policy(cfg, arenas), formulation)
        sizes = [int(s) for s in policy.discretization.sizes()]
        agent = TabularAgent(policy, Phase2Config())
        sim_rate(cfg, "random", 8, 0.05)  # compile (or load the numba cache) outside the measurement
        _actor_trials(cfg, agent, arenas, 0.0, batch_size, seed=1)  # one warm-up trial
        bar.mark(f"{sum(sizes) / len(sizes):.0f} prototypes per action", n=1)
        sim_steps = sim_s = 0.0
        totals = {"steps": 0.0, "tuples": 0.0, "slice_s": 0.0, "message_s": 0.0}
        for r in range(rounds):
            bar.show(status=f"round {r + 1}/{rounds}: simulator")
            start = time.perf_counter()
            rate = sim_rate(cfg, "random", arenas, seconds)
            took = time.perf_counter() - start
            sim_steps, sim_s = sim_steps + rate * took, sim_s + took
            bar.mark(f"simulator {rate / 1e6:.2f} M robot-steps/s", n=bar.n + 1)
            bar.show(status=f"round {r + 1}/{rounds}: actor slice")
            part = _actor_trials(cfg, agent, arenas, seconds, batch_size, seed=2 + r)
            totals = {key: totals[key] + part[key] for key in totals}
            bar.mark(f"actor {part['steps'] / part['slice_s'] / 1e3:.0f} k robot-steps/s", n=bar.n + 1)
    actor_rate = totals["steps"] / totals["slice_s"]
    simulator_rate = sim_steps / sim_s
    return {
        "benchmark": "actor",
        "scenario": cfg.name,
        "trial_rules": policy.formulation.trial_rules.name,
        "arenas": arenas,
        "robots": cfg.n_robots,
        "robot_steps_per_s": round(actor_rate),
        "sim_robot_steps_per_s": round(simulator_rate),
        "ratio": round(actor_rate / simulator_rate, 4),
        "tuples_per_s": round(totals["tuples"] / (totals["slice_s"] + totals["message_s"])),
        "slice_tuples_per_s": round(totals["tuples"] / totals["slice_s"]),
        "message_share": round(totals["message_s"] / (totals["slice_s"] + totals["message_s"]), 4),
        "prototypes_per_action": sizes,
        "target": {"ratio": ACTOR_TARGET_RATIO},
        "meets_target": {"ratio": actor_rate / simulator_rate >= ACTOR_TARGET_RATIO},
    }


def actor_table(out: dict[str, Any]) -> str:
    sizes = out["prototypes_per_action"]
    met = "met" if out["meets_target"]["ratio"] else "NOT met"
    return (
        f"actor slice: {out['robot_steps_per_s'] / 1e3:.0f} k robot-steps/s, {out['tuples_per_s'] / 1e3:.0f} k "
        f"tuples/s ({out['arenas']} arenas, {sum(sizes) / len(sizes):.0f} prototypes per action, trial rules "
        f"{out['trial_rules']})\n"
        f"simulator:   {out['sim_robot_steps_per_s'] / 1e6:.2f} M robot-steps/s (random controller, same arenas)\n"
        f"ratio {out['ratio']:.3f} (target >= {out['target']['ratio']}: {met})"
    )
