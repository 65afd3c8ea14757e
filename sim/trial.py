"""Learning trials as pure, batch-first functions: the trial rules written once, for E arenas × m robots.

The rules [paper §4; choices as tagged]:

* a trial lasts ``learning_steps`` steps; learning robots start within sensing range of a random target [choice];
* an action (a move of an action set: compass, or relative to the nearest target, :mod:`sim.actions`) is held for
  ``action_steps`` steps, in the frame it was chosen in; a caller may end actions on its own boundary as well
  (VQQL: "the discretized state changed", with a cap [paper]) through :meth:`TrialStep.with_boundary`;
* the reward is one of :data:`sim.features.REWARDS`: by default delayed to the end of the trial, 0 before it and
  paper Eq. 2 at it; a per-decision reward is paid at the end of every action instead;
* a learning robot that loses every target gets ``lost_reward``, its trial ends [choice] and it stays motionless
  [paper]; the formulation's :class:`~sim.formulation.TrialRules` may let it search on instead, and let the time-out
  bootstrap [beyond the paper];
* robots that do not learn follow the caller's actions, or a controller's velocity, and when lost search by keeping
  a heading reflected off the wall, which a ``track`` action set also turns to the law's pull
  (:meth:`sim.actions.ActionSet.steer`) [choice, as in test trials];
* a state that remembers (``Featurizer.recalls``) is read from :func:`sim.recall.recall`'s view, and so are the
  frame of a relative move and who counts as lost for the search: a robot still remembering its last target decides
  instead of searching; the rewards and the trial rules read what is sensed [beyond the paper].

Call sequence::

    rng = np.random.default_rng(seed)
    formulation = FORMULATIONS["paper"]              # the state, reward, action set and trial rules
    state = reset_trial(cfg, n_arenas=E, learners=np.arange(m) == 0, formulation=formulation, rng=rng)
    decide = np.ones(state.shape, bool)              # every robot takes a first action
    while True:
        action = explore_actions(cfg, state, rng)    # or a policy's (E, m) actions; read only where ``decide``
        state, out = step_trial(cfg, state, action, decide, rng)
        ends = out.transition                        # robots whose tuple ⟨s, a, r, s′, done⟩ ends here:
        # out.start_features[ends], out.action[ends], out.reward[ends], out.next_features[ends], out.done[ends]
        if out.trial_over:
            break
        decide = out.decide

Nothing here modifies its inputs (unless told to update a state's tracks in place); all randomness comes from the
``rng`` passed in, in a fixed order, so the experience slice and the Gymnasium / PettingZoo adapters reproduce each
other's trajectories from one seed.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from sim import _kernels
from sim.config import ScenarioConfig
from sim.controllers import N_ACTIONS
from sim.features import lost, step_value, trial_reward
from sim.formulation import Formulation
from sim.recall import Recall, forget_all, view_of
from sim.world import Observation, WorldState, place_near_targets, reset, sense, step


@dataclass(frozen=True, slots=True)
class TrialState:
    """Everything a learning trial carries from one step to the next, for E arenas × m robots."""

    world: WorldState
    obs: Observation
    """What every robot perceives in ``world``."""
    view: Observation
    """What its state and moves read: ``obs``, or for a state that remembers, ``obs`` with each lost robot's
    remembered target (:mod:`sim.recall`)."""
    recall: Recall | None
    """Every robot's memory of its last sighting, for a state that remembers; None otherwise."""
    formulation: Formulation
    """The state of ``features``, the learners' reward, the action set of the action indices, the trial rules."""
    features: np.ndarray | None
    """(E, m, d) float32: every robot's state now; None after a :func:`step_trial` with ``lazy`` on which no robot's
    action or trial ended (nothing reads it before the next state's)."""
    action: np.ndarray
    """(E, m) int64: the action each robot holds (an index of the formulation's action set)."""
    held: np.ndarray
    """(E, m) int64: steps the held action has lasted."""
    start_features: np.ndarray
    """(E, m, d) float32: each robot's state when it chose the held action (the s of its next tuple)."""
    frame: np.ndarray
    """(E, m, 2, 2) float64: the frame the held action is named in, fixed when it was chosen (rows: x, y axes)."""
    move: np.ndarray
    """(E, m, 2) float64: the held action's full-speed displacement in that frame, computed when it was chosen (the
    search and stop rules override it step by step)."""
    learner: np.ndarray
    """(E, m) bool: robots that learn; their trial ends when they lose every target (paper rules)."""
    active: np.ndarray
    """(E, m) bool: learners whose trial goes on."""
    heading: np.ndarray
    """(E, m, 2) float64 unit vectors: the search heading of robots that search while they are lost (those that do not
    learn, and learners whose rules let them search on), and the x axis of a ``search`` action set's frame where the
    law pulls nowhere."""
    earned: np.ndarray
    """(E, m) float32: a per-decision reward's value summed over the held action's steps so far (0 otherwise)."""

    @property
    def shape(self) -> tuple[int, int]:
        """(E, m)."""
        n_arenas, m = self.action.shape
        return n_arenas, m

    def require_features(self) -> np.ndarray:
        """:attr:`features`, which every state has but one a ``lazy`` step left out."""
        if self.features is None:
            raise ValueError("this state's features were left out: a lazy step on which no action ended made it")
        return self.features


@dataclass(frozen=True, slots=True)
class TrialStep:
    """What one step of a trial produced; a robot's tuple ends where :attr:`transition` is set."""

    start_features: np.ndarray
    """(E, m, d) float32: s, the state in which the action held during this step was chosen."""
    action: np.ndarray
    """(E, m) int64: a, the action held during this step."""
    next_features: np.ndarray | None
    """(E, m, d) float32: s′, the state after this step; None where the new state's ``features`` are (``lazy``, no
    tuple ends here)."""
    reward: np.ndarray
    """(E, m) float32: r of the tuples that end here (``lost_reward`` for a robot that lost every target), 0 elsewhere:
    a trial-end reward's value where ``done``, a per-decision reward's mean over the action where it ends."""
    done: np.ndarray
    """(E, m) bool: learners whose tuple ending on this step is terminal: they lost every target (with
    :attr:`~sim.formulation.TrialRules.lost_ends_trial`), or it was the last step (with
    :attr:`~sim.formulation.TrialRules.timeout_terminal`)."""
    truncated: np.ndarray
    """(E, m) bool: learners whose trial the time-out cut on this step without a terminal tuple (their tuple ends
    here and bootstraps from s′; ``timeout_terminal`` False)."""
    boundary: np.ndarray
    """(E, m) bool: the held action ended on this step (its length reached, or the caller's own boundary)."""
    active: np.ndarray
    """(E, m) bool: learners whose trial goes on after this step."""
    learner: np.ndarray
    """(E, m) bool: robots that learn."""
    trial_over: bool
    """This was the last step of the trial."""
    action_mean: np.ndarray | None = None
    """(E, m) float32: a per-decision reward's mean value over the held action's steps; None for trial-end rewards."""

    @property
    def transition(self) -> np.ndarray:
        """(E, m) bool: learners whose tuple ⟨s, a, r, s′, done⟩ ends on this step."""
        return self.done | self.truncated | (self.active & self.boundary)

    def require_next_features(self) -> np.ndarray:
        """:attr:`next_features`, which every step has but a ``lazy`` one on which no tuple ends."""
        if self.next_features is None:
            raise ValueError("this step's s′ was left out: a lazy step on which no action ended")
        return self.next_features

    @property
    def decide(self) -> np.ndarray:
        """(E, m) bool: robots that take a new action before the next step (a learner whose trial ended never does)."""
        return self.boundary & (self.active | ~self.learner)

    def with_boundary(self, extra: np.ndarray) -> TrialStep:
        """The same step with the robots of ``extra`` (E, m) bool also ending their action, e.g. VQQL's cell change.

        Usage::

            state, out = step_trial(cfg, state, action, decide, rng, hold=max_action_steps)
            out = out.with_boundary(cell_now != cell_at_decision)
        """
        out = dataclasses.replace(self, boundary=self.boundary | np.asarray(extra, dtype=bool))
        if out.action_mean is None:
            return out
        return dataclasses.replace(out, reward=np.where(out.transition & ~out.done, out.action_mean, out.reward))


def reset_trial(
    cfg: ScenarioConfig,
    n_arenas: int,
    learners: np.ndarray,
    formulation: Formulation,
    rng: np.random.Generator,
    world: WorldState | None = None,
) -> TrialState:
    """E fresh arenas whose ``learners`` (bool, broadcastable to (E, m)) start within sensing range of a target, or,
    given ``world``, a trial in those arenas as they are (its clock restarted: the trial's own steps).

    ``formulation`` gives the state, the learners' reward, the action set and the trial rules. No robot holds an
    action yet: the first :func:`step_trial` must let every robot decide.
    """
    learner = np.broadcast_to(np.asarray(learners, dtype=bool), (n_arenas, cfg.n_robots)).copy()
    if world is None:
        world = place_near_targets(cfg, reset(cfg, n_arenas, rng), learner, rng)
    else:
        world = dataclasses.replace(world, t=0)
    obs = sense(cfg, world, rng)
    memory = forget_all(cfg, learner.shape) if formulation.featurizer.recalls else None
    view, memory = view_of(cfg, world, obs, memory)
    features = formulation.featurizer.compute(cfg, view)
    angle = rng.uniform(0.0, 2.0 * np.pi, learner.shape)
    heading = np.stack([np.cos(angle), np.sin(angle)], axis=-1)
    action = np.zeros(learner.shape, np.int64)
    frame = np.array(formulation.actions.frame(view, heading), dtype=np.float64)
    return TrialState(
        world=world,
        obs=obs,
        view=view,
        recall=memory,
        formulation=formulation,
        features=features,
        action=action,
        held=np.zeros(learner.shape, np.int64),
        start_features=features,
        frame=frame,
        move=formulation.actions.velocity(cfg, action, frame),
        learner=learner,
        active=learner.copy(),
        heading=heading,
        earned=np.zeros(learner.shape, np.float32),
    )


def random_actions(state: TrialState, rng: np.random.Generator) -> np.ndarray:
    """(E, m) uniform action indices, the exploration rule [choice].

    Drawn for every robot, whoever decides, so that the random stream does not depend on who is deciding.
    """
    return rng.integers(0, N_ACTIONS, state.shape)


def explore_actions(cfg: ScenarioConfig, state: TrialState, rng: np.random.Generator) -> np.ndarray:
    """(E, m) random exploration's actions: :func:`random_actions`, and where the trial rules have a guide
    (:class:`sim.guide.Guide`), the guide's move instead at its ``explore`` share of them [beyond the paper].

    Without a guide this draws exactly what :func:`random_actions` draws.
    """
    actions = random_actions(state, rng)
    guide = state.formulation.trial_rules.guide
    if guide is not None and guide.explore > 0:
        take = np.flatnonzero(rng.random(state.shape) < guide.explore)
        if take.size:
            actions.reshape(-1)[take] = guide.actions(cfg, state, take)
    return actions


# Over 60 lines: the trial rules of one step in the order the paper applies them, kept in one place so that the
# order reads top to bottom (each rule is a few numpy lines).
def step_trial(
    cfg: ScenarioConfig,
    state: TrialState,
    action: np.ndarray,
    decide: np.ndarray,
    rng: np.random.Generator,
    *,
    velocity: np.ndarray | None = None,
    hold: int | None = None,
    in_place: bool = False,
    lazy: bool = False,
) -> tuple[TrialState, TrialStep]:
    """Advance every arena one step under the trial rules.

    ``action`` (E, m) action indices is read only where ``decide`` (E, m) bool: those robots start a new action
    now (every robot on the first step, then ``out.decide`` of the previous step). ``velocity`` (E, m, 2), if
    given, moves the robots that do not learn instead of their actions and search, e.g. a hand-made controller's.
    ``hold`` is the length after which an action ends (default ``cfg.action_steps``; VQQL passes its cap).
    ``in_place``: a remembering state's tracks are updated in place (:func:`sim.recall.recall`), so ``state`` must not
    be stepped again (a caller that keeps only the newest state, as the experience slice does); otherwise nothing
    passed in is modified. ``lazy``: the new state's features are computed only when some robot's action or trial ends
    on this step, the only steps after which they are read (as s′, and as the s of the next decisions); otherwise they
    are None. Held actions end together, so a learning slice computes them on one step in ``cfg.action_steps``; a
    caller that reads them every step (an environment's observation, VQQL's cell change) keeps the default.
    """
    if state.world.t >= cfg.learning_steps:
        raise ValueError(f"the trial is over: it lasts {cfg.learning_steps} steps")
    decide = np.asarray(decide, dtype=bool)
    if decide.shape != state.shape:
        raise ValueError(f"decide must have shape {state.shape}, got {decide.shape}")
    formulation = state.formulation
    moves, rules = formulation.actions, formulation.trial_rules
    held_action, start, held, frame, held_move = state.action, state.start_features, state.held, state.frame, state.move
    # Only robots that do not learn search (and learners, where losing every target does not end their trial); with
    # none in the batch, and moves not named from it, the headings are never read. They turn before the robots
    # decide, so a search set's move "law" is the law's own move of this step.
    seeker = ~state.learner | (not rules.lost_ends_trial)
    steered = seeker.any() or moves.search
    heading = moves.steer(cfg, state.world, state.view, state.heading) if steered else state.heading
    if decide.any():
        held_action = np.where(decide, action, held_action)
        if held_action.min() < 0 or held_action.max() >= N_ACTIONS:
            raise ValueError(f"actions must be integers in [0, {N_ACTIONS})")
        start = np.where(decide[..., None], state.require_features(), start)
        held = np.where(decide, 0, held)
        if moves.relative:
            frame = np.where(decide[..., None, None], moves.frame(state.view, heading), frame)
        held_move = moves.velocity(cfg, held_action, frame)
    # A new array: the rules below overwrite its robots' rows.
    move = held_move.copy() if velocity is None else np.where(state.learner[..., None], held_move, velocity)
    if velocity is not None:
        seeker = seeker & state.learner
    searching = seeker & lost(state.view)
    # Searchers move along their heading; a learner whose trial ended stays where it lost its targets [paper].
    _kernels.override_moves(move, searching, heading, cfg.robot_speed, state.learner & ~state.active)
    world = step(cfg, state.world, move, rng)
    obs = sense(cfg, world, rng)
    view, memory = view_of(cfg, world, obs, state.recall, in_place=in_place)
    held = held + 1
    trial_over = world.t >= cfg.learning_steps
    gone = lost(obs)
    per_decision = formulation.reward.per_decision
    # A trial-end reward is paid only at the end, so its time-out is always terminal.
    timeout_ends = trial_over and (rules.timeout_terminal or not per_decision)
    lost_ends = gone & rules.lost_ends_trial
    done = state.active & (lost_ends | timeout_ends)
    truncated = state.active & ~done & trial_over
    active = state.active & ~done & ~truncated
    boundary = held >= (cfg.action_steps if hold is None else hold)
    read = not lazy or bool(boundary.any() or done.any() or truncated.any())
    features = formulation.featurizer.compute(cfg, view) if read else None
    earned, action_mean = state.earned, None
    if per_decision:
        # The value summed over the held action's steps (restarted where a robot decided), its mean, and the reward
        # of the tuples that end here: the mean, or lost_reward for a learner whose losing ends its trial.
        value = step_value(cfg, state.obs, obs, formulation.reward)
        earned, action_mean, reward = (np.empty(state.shape, np.float32) for _ in range(3))
        _kernels.decision_rewards(
            decide,
            state.earned,
            value,
            held,
            done & lost_ends,
            done | truncated | (active & boundary),
            np.float32(cfg.lost_reward),
            earned,
            action_mean,
            reward,
        )
    elif done.any():
        reward = np.where(done, trial_reward(cfg, obs, formulation.reward), 0.0).astype(np.float32)
    else:
        reward = np.zeros(state.shape, np.float32)
    out = TrialStep(
        start_features=start,
        action=held_action,
        next_features=features,
        reward=reward,
        done=done,
        truncated=truncated,
        boundary=boundary,
        active=active,
        learner=state.learner,
        trial_over=trial_over,
        action_mean=action_mean,
    )
    new_state = TrialState(
        world=world,
        obs=obs,
        view=view,
        recall=memory,
        formulation=formulation,
        features=features,
        action=held_action,
        held=held,
        start_features=start,
        frame=frame,
        move=held_move,
        learner=state.learner,
        active=active,
        heading=heading,
        earned=earned,
    )
    return new_state, out
