"""Keeping a run's best policy by its validation trials (``algorithm.selection``)."""

from __future__ import annotations

import numpy as np

from algorithm.discretization import Discretization
from algorithm.policy import Policy, PolicyController
from algorithm.selection import VALIDATION_SEED, BestPolicy
from sim import N_ACTIONS, evaluate, scenario
from sim.formulation import DEFAULT_FORMULATION, FORMULATIONS

CFG = scenario("cmommt-v1")
FORMULATION = FORMULATIONS[DEFAULT_FORMULATION]


def constant(action: int, version: int) -> Policy:
    """A policy that always takes ``action``: one cell per action, the highest value on ``action``'s."""
    disc = Discretization.from_per_action([np.zeros((1, FORMULATION.dim), np.float32)] * N_ACTIONS)
    tables = np.zeros((1, N_ACTIONS), np.float32)
    tables[0, action] = 1.0
    return Policy(
        formulation=FORMULATION,
        discretization=disc,
        tables=tables,
        robot_table=np.zeros(CFG.n_robots, np.int64),
        action_steps=1,
        version=version,
    )


def validation(policy: Policy, trials: int) -> float:
    return evaluate(CFG, PolicyController(policy), trials, 100, seed=VALIDATION_SEED).coverage_mean


def test_the_best_on_the_validation_trials_is_kept_whenever_it_came() -> None:
    policies = [constant(a, version=a + 1) for a in range(N_ACTIONS)]
    scores = [validation(p, 3) for p in policies]
    assert len(set(scores)) > 2  # the actions differ, so the choice is not a tie
    best = int(np.argmax(scores))
    # The best in the middle, a worse one last: the last policy is not the one kept.
    worse = int(np.argmin(scores))
    order = [i for i in range(N_ACTIONS) if i not in (best, worse)]
    order = [*order[:3], best, *order[3:], worse]
    keeper = BestPolicy(CFG, trials=3, steps=100)
    offered = [keeper.offer(policies[i], at=float(k)) for k, i in enumerate(order)]
    assert offered == [scores[i] for i in order]  # the validation trials are the seed's, the same every time
    assert keeper.best is not None and keeper.best.policy is policies[best]
    assert keeper.best.coverage == max(scores) and keeper.best.at == float(order.index(best))
    assert [c for _, c in keeper.scores] == [round(scores[i], 3) for i in order]
    # A tie keeps the earlier policy.
    keeper.offer(constant(best, version=99), at=99.0)
    assert keeper.best.policy is policies[best]


def test_the_validation_trials_are_not_the_test_trials() -> None:
    policy = constant(0, version=1)
    test = evaluate(CFG, PolicyController(policy), 20, 100, seed=0).coverage_per_trial
    valid = evaluate(CFG, PolicyController(policy), 20, 100, seed=VALIDATION_SEED).coverage_per_trial
    assert not np.isin(valid, test).all()  # other arenas, not the reported ones reordered


def test_the_kept_policy_survives_a_restore_and_is_forgotten_without_its_file() -> None:
    keeper = BestPolicy(CFG, trials=2, steps=100)
    first, second = constant(1, version=1), constant(5, version=2)
    keeper.offer(first, at=1.0)
    keeper.offer(second, at=2.0)
    assert keeper.best is not None
    meta = keeper.to_meta()
    again = BestPolicy(CFG, trials=2, steps=100)
    again.restore(meta, keeper.best.policy)
    assert again.scores == keeper.scores and again.best is not None
    assert (again.best.coverage, again.best.at) == (keeper.best.coverage, keeper.best.at)
    lost = BestPolicy(CFG, trials=2, steps=100)
    lost.restore(meta, None)
    assert lost.best is None and lost.scores == keeper.scores
    lost.offer(first, at=3.0)  # the next offer is kept, whatever its score
    assert lost.best is not None and lost.best.policy is first
