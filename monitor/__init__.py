"""Rerun monitoring: every process of a run (learner, actors, ``up``, ``eval``) logs into ONE recording.

Call sequence in a process::

    parser = argparse.ArgumentParser(); add_rerun_args(parser)      # --rerun off|save PATH|spawn|connect URL|serve
    args = parser.parse_args()                                      #   and --recording-id ID
    with open_monitor(sink_from_args(args), process="learner", recording_id=args.recording_id) as monitor:
        monitor.use_clock(run_clock)                                    # train_time: seconds of training
        monitor.send_blueprint(["actor-0", "actor-1"], arena_radius=1000.0, sensing_range=150.0)   # learner
        monitor.reference_levels({"random": 16.6, "local": 56.3, "a-cmommt": 72.1})               # once
        monitor.learner_metrics(learner_step=i, policy_version=v, tuples_per_s=..., live_actors=2,
                                store_size=..., rejected=0, lag={"actor-0": 1})
        monitor.eval_coverage(59.4, policy_version=v, learner_step=i)
        monitor.final_coverage(61.5, trials=50, policy_version=v, learner_step=i)   # at the end
        monitor.q_stats(tables, policy_version=v)
        monitor.prototypes(prototypes_per_action, q_per_action, policy_version=v)
        # in an actor:
        monitor.arena(paths.actor_arena("actor-0"), robot_pos, target_pos,
                      sensing_range=cfg.sensing_range, arena_radius=cfg.arena_radius, sim_step=t)
        monitor.actor_metrics("actor-0", sim_step=t, coverage=58.1, mean_reward=0.7, tuples_per_s=1e5)
        monitor.scalars("actors/actor-0", {"outbox": 12.0}, sim_step=t)             # anything else

- **One recording.** Every stream uses application id ``"ennc-ql"`` and the recording id it is given; the launcher
  picks one id and passes it to every child (``--recording-id``). Library code logs through a
  ``rr.RecordingStream`` the monitor owns, never the global recording.
- **Off costs nothing.** ``--rerun off`` (the default) gives the base :class:`Monitor`, whose methods return at
  once; Rerun is imported only when another sink is opened (``import monitor`` never loads it).
- **Timelines** (names in :mod:`monitor.paths`): ``sim_step`` (actor's simulation step, or the step of a recorded
  trial), ``policy_version`` (learner), ``learner_step`` (iterations of the learner's main loop, one per status
  publish; evaluation points carry the iteration they ran in), and on every row ``train_time`` (seconds of
  training, the x-axis of the default layout: the clock given to ``use_clock``) and ``wall_time``. Each call
  attaches exactly the sequence timelines passed to it.
- **Entity paths** (:mod:`monitor.paths`): ``actors/<id>/arena/{boundary,sensing,robots,targets}``,
  ``actors/<id>/{coverage,reward,tuples_per_s,policy_version,rss_mb}``, ``learner/coverage/{eval,final}``,
  ``learner/coverage/reference/<controller>``, ``learner/{tuples_per_s,policy_version,live_actors,store_size,
  rejected,rss_mb}``, ``learner/lag/<id>``, ``learner/q/{mean,min,max}``, ``learner/prototypes/action_<k>``, the
  colour key ``key/...``, and for a recorded test trial ``eval/arena/...`` and ``eval/coverage``.
- **The layout** (:mod:`monitor.layout`): the learning curve first, over the whole run, the viewer opening at the
  end; colours in :mod:`monitor.style` (one per actor in every panel); 2-D views north up (:mod:`monitor.paths`).
- **Several processes, one file.** Processes cannot share one .rrd: under ``ennc-ql up`` each child saves
  ``paths.part_file(run_dir, process)`` (``runs/<id>/rerun/<process>.rrd``) with the shared recording id, and the
  launcher calls :func:`merge_recordings` into ``runs/<id>/recording.rrd`` at the end; :func:`summarize_recording`
  reads a file back (recording ids, entity paths, row counts).
- **Replaying a test trial**: :func:`monitor.trial.record_trial` (imported from its module, as it brings in the
  simulator).
- **Watchers** (imported from their modules): an actor's learning trial goes through
  :class:`monitor.trial.TrialWatch`, the learner's figures through :class:`monitor.learner.LearnerWatch`, which does
  nothing, not even the work of preparing a call, when the monitor is off.
"""

from monitor import paths
from monitor.interface import Monitor
from monitor.recordings import RecordingError, merge_recordings, summarize_recording
from monitor.sinks import Sink, add_rerun_args, open_monitor, sink_from_args

__all__ = [
    "Monitor",
    "RecordingError",
    "Sink",
    "add_rerun_args",
    "merge_recordings",
    "open_monitor",
    "paths",
    "sink_from_args",
    "summarize_recording",
]
