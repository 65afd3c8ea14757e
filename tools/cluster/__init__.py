"""The local cluster as a library: one learner and N actors on this machine, as OS processes on loopback Zenoh or as
objects in this process on the in-memory bus (serial mode), with the same report. ``ennc-ql up`` is a thin command
over it, and ``ennc-ql chaos`` starts its cluster with the same pieces.

Usage::

    config = load_config(UpConfig, defaults=UP_PRESETS)
    learner, actors = child_configs(config)
    write_configs(config, learner, actors, run_dir)
    report = run_serial(learner, actors, run_dir)                                      # one process
    run = run_processes(learner, actors, run_dir, monitoring, "run-x")                 # as OS processes
    done = run_to_report(learner, actors, run_dir, monitoring, "run-x")                # ... and the learner's report
"""

# The package, by role: config (UpConfig, up's presets, each child's configuration), serial (the serial topology),
# processes (the process topology, its placement and its progress bar), children (child processes, their supervision),
# endpoints (how each process joins a run: peer-to-peer or through a router, plain or secure), recording (Rerun),
# launch (the processes to the learner's report, and the launcher's summary beside it: up and a SLURM job alike),
# report (report.json typed: the learner's report and the launcher's figures as one RunReport).

from tools.cluster.children import ACTOR_NICENESS, Children, Restart, Supervisor, ennc_ql_argv, log_tail
from tools.cluster.config import SET_BY_UP, UP_PRESETS, UpConfig, child_configs, write_configs
from tools.cluster.endpoints import Endpoints, make_endpoints
from tools.cluster.launch import Finished, RunSummary, run_to_report
from tools.cluster.processes import LaunchError, Placement, ProcessRun, cluster_status, run_processes
from tools.cluster.recording import Monitoring
from tools.cluster.report import Interruption, LaunchFigures, RecordingFigures, RunReport, SlurmFigures
from tools.cluster.serial import run_serial

__all__ = [
    "ACTOR_NICENESS",
    "SET_BY_UP",
    "UP_PRESETS",
    "Children",
    "Endpoints",
    "Finished",
    "Interruption",
    "LaunchError",
    "LaunchFigures",
    "Monitoring",
    "Placement",
    "ProcessRun",
    "RecordingFigures",
    "Restart",
    "RunReport",
    "RunSummary",
    "SlurmFigures",
    "Supervisor",
    "UpConfig",
    "child_configs",
    "cluster_status",
    "ennc_ql_argv",
    "log_tail",
    "make_endpoints",
    "run_processes",
    "run_serial",
    "run_to_report",
    "write_configs",
]
