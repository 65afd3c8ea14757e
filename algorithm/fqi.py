"""A neural fitted-Q reference: a small torch MLP Q(s) -> (Q(s, a))_a on the same tuples and state as ENNC-QL.

It is not ENNC-QL and never stands in for it: it is scored beside it (``ennc-ql ablate fqi-mlp``) to tell what a
smooth function approximator reaches on the same state, reward and amount of experience, i.e. whether what separates
ENNC-QL from a hand-made law is its discretization or the credit its reward gives [beyond the paper].

The process: random exploration (as ENNC-QL's phase 0), ``iterations`` fitted-Q iterations on it, then ``rounds``
rounds that each collect ε-greedy learning trials with the current network and refit on the newest
``buffer`` tuples. Usage::

    q = QNetwork.for_states(data.state, FQIConfig(), seed=0)
    fit_q(q, data, FQIConfig(), rng)
    actions = q.greedy(states)                    # (N,) argmax_a Q(s, a)
    evaluate(cfg, NetworkController(q, FORMULATIONS["shared-difference"]), trials=10, steps=1000)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from algorithm.transitions import Transitions
from sim import ScenarioConfig
from sim.controllers import random_headings
from sim.features import lost
from sim.formulation import Formulation
from sim.recall import Recall, forget_all, view_of
from sim.trial import reset_trial, step_trial
from sim.world import Observation, WorldState

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True, slots=True)
class FQIConfig:
    hidden: int = 128
    """Units of each of the two hidden layers."""
    iterations: int = 15
    """Fitted-Q iterations on the exploration data."""
    round_iterations: int = 5
    """Fitted-Q iterations after each round of on-policy trials."""
    steps: int = 300
    """Adam steps per iteration (minibatches of ``batch_size``)."""
    batch_size: int = 2048
    """Transitions per Adam step."""
    lr: float = 1e-3
    """Adam's learning rate."""
    gamma: float = 0.9
    """Discount per decision, as phase 2's."""
    epsilon: float = 0.1
    """Exploration of the on-policy rounds, as phase 2's."""
    rounds: int = 6
    """Rounds of on-policy learning trials; the budget's phase-2 batches are split evenly between them."""
    buffer: int = 3_000_000
    """Tuples kept (the newest)."""


class QNetwork:
    """Q(s, ·) for the 8 actions: inputs standardized with the exploration data's statistics."""

    def __init__(self, dim: int, config: FQIConfig, mean: np.ndarray, std: np.ndarray, seed: int) -> None:
        import torch

        torch.manual_seed(seed)
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.net = torch.nn.Sequential(
            torch.nn.Linear(dim, config.hidden),
            torch.nn.ReLU(),
            torch.nn.Linear(config.hidden, config.hidden),
            torch.nn.ReLU(),
            torch.nn.Linear(config.hidden, 8),
        )

    @classmethod
    def for_states(cls, states: np.ndarray, config: FQIConfig, seed: int) -> QNetwork:
        s = np.asarray(states, np.float64)
        std = s.std(axis=0)
        return cls(s.shape[1], config, s.mean(axis=0), np.where(std > 1e-9, std, 1.0), seed)

    def forward(self, states: Any) -> torch.Tensor:
        import torch

        return self.net((torch.as_tensor(states, dtype=torch.float32) - self.mean) / self.std)

    def values(self, states: np.ndarray) -> np.ndarray:
        """(N, 8) Q values."""
        import torch

        with torch.no_grad():
            parts = [self.forward(states[i : i + 65536]).numpy() for i in range(0, len(states), 65536)]
        return np.concatenate(parts) if parts else np.zeros((0, 8), np.float32)

    def greedy(self, states: np.ndarray) -> np.ndarray:
        return self.values(states).argmax(axis=1)


def fit_q(q: QNetwork, data: Transitions, config: FQIConfig, iterations: int, rng: np.random.Generator) -> None:
    """``iterations`` fitted-Q iterations: targets r + γ·max_b Q(s′, b) (r where s′ is terminal) from the network
    as it stands, then ``steps`` Adam steps on the squared error of the taken action's value."""
    import torch

    opt = torch.optim.Adam(q.net.parameters(), lr=config.lr)
    states = torch.as_tensor(data.state, dtype=torch.float32)
    actions = torch.as_tensor(data.action.astype(np.int64))
    rewards = torch.as_tensor(data.reward, dtype=torch.float32)
    done = torch.as_tensor(data.done)
    for _ in range(iterations):
        bootstrap = torch.as_tensor(q.values(data.next_state).max(axis=1))
        target = torch.where(done, rewards, rewards + config.gamma * bootstrap)
        for _ in range(config.steps):
            rows = torch.as_tensor(rng.integers(0, len(data), config.batch_size))
            taken = q.forward(states[rows]).gather(1, actions[rows, None])[:, 0]
            loss = torch.nn.functional.mse_loss(taken, target[rows])
            opt.zero_grad()
            loss.backward()
            opt.step()


def collect(
    cfg: ScenarioConfig,
    q: QNetwork | None,
    formulation: Formulation,
    arenas: int,
    epsilon: float,
    rng: np.random.Generator,
) -> Transitions:
    """One learning trial in ``arenas`` arenas under :mod:`sim.trial`'s rules, every robot learning (option 2's
    slice): random actions without a network, ε-greedy ones with it; the tuples of every robot."""
    state = reset_trial(cfg, arenas, np.ones(cfg.n_robots, bool), formulation, rng)
    decide = np.ones(state.shape, bool)
    parts = []
    while True:
        chosen = rng.integers(0, 8, state.shape)
        if q is not None:
            features = state.require_features()
            greedy = q.greedy(features.reshape(-1, features.shape[-1])).reshape(state.shape)
            chosen = np.where(rng.random(state.shape) < epsilon, chosen, greedy)
        state, out = step_trial(cfg, state, chosen, decide, rng)
        ends = out.transition
        if ends.any():
            parts.append(
                Transitions(
                    robot=np.broadcast_to(np.arange(ends.shape[1]), ends.shape)[ends].astype(np.int16),
                    state=out.start_features[ends],
                    action=out.action[ends].astype(np.uint8),
                    reward=out.reward[ends],
                    next_state=out.require_next_features()[ends],
                    done=out.done[ends],
                )
            )
        if out.trial_over:
            return Transitions.concat(parts) if parts else Transitions.empty(state.require_features().shape[-1])
        decide = out.decide


_NetworkMemory = tuple[np.ndarray, np.ndarray, Recall | None]


@dataclass(frozen=True, slots=True)
class NetworkController:
    """Every robot greedy on the network, deciding every ``act_every`` steps; a robot that sees no target keeps a
    heading reflected off the wall, as the learned policies and the hand-made laws do."""

    q: QNetwork
    formulation: Formulation
    """Its state and action set."""
    act_every: int = 1
    name: str = "fqi-mlp"

    def init(self, cfg: ScenarioConfig, world: WorldState, rng: np.random.Generator) -> _NetworkMemory:
        """(heading of a searching robot, velocity of the move chosen last, the robots' last sightings)."""
        shape = (world.n_arenas, cfg.n_robots)
        recall = forget_all(cfg, shape) if self.formulation.featurizer.recalls else None
        return random_headings(cfg, world, rng), np.zeros((*shape, 2)), recall

    def act(
        self,
        cfg: ScenarioConfig,
        world: WorldState,
        obs: Observation,
        memory: _NetworkMemory,
        rng: np.random.Generator,
    ) -> tuple[np.ndarray, _NetworkMemory]:
        heading, velocity, recall = memory
        view, recall = view_of(cfg, world, obs, recall)
        moves = self.formulation.actions
        heading = moves.steer(cfg, world, view, heading)
        if world.t % self.act_every == 0:
            states = self.formulation.featurizer.compute(cfg, view)
            chosen = self.q.greedy(states.reshape(-1, states.shape[-1])).reshape(states.shape[:2])
            velocity = moves.velocity(cfg, chosen, moves.frame(view, heading))
        move = np.where(lost(view)[..., None], cfg.robot_speed * heading, velocity)
        return move, (heading, velocity, recall)
