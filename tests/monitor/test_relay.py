"""An actor's viewer rows relayed to the learner (``--rerun learner``): what the relay sends, and that nothing it
fails at stops the actor. The learner's side, through the runtime, is ``test_runtime.py``'s relayed case."""

from __future__ import annotations

import numpy as np
import pytest

from monitor import Sink, open_monitor, paths
from monitor.relay import RelayMonitor
from protocol import ActorView, decode, encode
from protocol.messages import MAX_VIEW_FRAMES


def frame(relay: RelayMonitor, step: int) -> None:
    robots = np.full((10, 2), step, np.float64)
    relay.arena(paths.actor_arena("a0"), robots, -robots, sensing_range=150.0, arena_radius=1000.0, sim_step=step)


def test_a_view_carries_the_frames_since_the_last_one_and_the_trials_figures() -> None:
    sent: list[ActorView] = []
    relay = RelayMonitor(lambda view: sent.append(decode(encode(view))), "a0")
    relay.use_clock(lambda: 7.5)
    for step in range(1, 4):
        frame(relay, step)
    relay.actor_metrics("a0", sim_step=3, coverage=40.0, tuples_per_s=None, policy_version=2)
    relay.actor_metrics("a0", sim_step=6, coverage=45.0)  # a trial not drawn: figures only
    first, second = sent
    assert first.frame_step.tolist() == [1, 2, 3] and first.frame_time.tolist() == [7.5] * 3
    assert first.robot_pos.shape == (3, 10, 2) and first.robot_pos[2, 0].tolist() == [3.0, 3.0]
    assert first.target_pos[1, 9].tolist() == [-2.0, -2.0]
    assert (first.sensing_range, first.arena_radius, first.sim_step, first.train_time) == (150.0, 1000.0, 3, 7.5)
    assert set(first.counters) == {"coverage", "policy_version", "rss_mb"}  # tuples_per_s was None
    assert first.counters["rss_mb"] > 10.0
    assert second.frame_step.size == 0 and second.counters["coverage"] == 45.0
    assert (relay.sent, relay.dropped) == (2, 0)


def test_a_view_that_cannot_be_built_or_sent_is_dropped_and_the_actor_goes_on() -> None:
    failures = iter([OSError("the session is gone"), None])
    sent: list[ActorView] = []

    def send(view: ActorView) -> None:
        error = next(failures)
        if error is not None:
            raise error
        sent.append(view)

    relay = RelayMonitor(send, "a0")
    frame(relay, 1)
    relay.actor_metrics("a0", sim_step=1, coverage=50.0)  # the send fails
    relay.actor_metrics("a0", sim_step=2, coverage=float("nan"))  # NaN: the view is invalid, never sent
    frame(relay, 3)
    relay.actor_metrics("a0", sim_step=3, coverage=55.0)
    assert (relay.sent, relay.dropped) == (1, 2)
    assert [v.frame_step.tolist() for v in sent] == [[3]]  # a failed view's frames are not sent again later


def test_a_long_trial_goes_in_views_of_at_most_the_frame_limit() -> None:
    sent: list[ActorView] = []
    relay = RelayMonitor(sent.append, "a0")
    for step in range(1, MAX_VIEW_FRAMES + 6):
        frame(relay, step)
    relay.actor_metrics("a0", sim_step=MAX_VIEW_FRAMES + 5, coverage=1.0)
    assert [v.frame_step.size for v in sent] == [MAX_VIEW_FRAMES, 5]
    assert dict(sent[0].counters) == {} and sent[1].counters["coverage"] == 1.0
    relay.close()
    relay.actor_metrics("a0", sim_step=1, coverage=1.0)
    assert len(sent) == 2 and not relay.enabled


def test_only_an_actor_relays() -> None:
    with pytest.raises(ValueError, match="--rerun learner is an actor's"):
        open_monitor(Sink("learner"), process="learner-0")
