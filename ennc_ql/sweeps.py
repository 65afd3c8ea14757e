"""``ennc-ql reproduce`` and ``ennc-ql ablate``: the sweeps (:mod:`tools.sweeps`), their learning processes run
here or as a SLURM job array, chosen once (:func:`sweep_backend`)::

    ennc-ql reproduce --quick --jobs 2
    ennc-ql ablate ennc-ql-collab-option2 --set budget.phase2.alpha=0.05,0.2 --processes 3 --jobs 2 --quick
    ennc-ql ablate ennc-ql-local --set budget.phase2.alpha=0.1,0.3 --slurm --sbatch='--partition=cpu'
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from algorithm.experiments import METHODS, Budget
from ennc_ql.command import check_folder, emit, fail, run_files
from ennc_ql.parser import CommandHelp, add_command
from sim.formulation import choices_help
from tools.config import ConfigError, add_config_flags, folder, load_config, positive
from tools.slurm.array import ArrayConfig, SlurmArray
from tools.slurm.sbatch import SlurmError
from tools.sweeps.ablate import Setup, ablate, check_used, parse_sets, variants
from tools.sweeps.ablate import markdown_table as ablation_table
from tools.sweeps.jobs import Backend, LocalProcesses
from tools.sweeps.reproduce import markdown_table as reproduce_table
from tools.sweeps.reproduce import method_names, reproduce
from tools.sweeps.results import RESULTS


def sweep_backend(slurm: ArrayConfig, jobs: int, out_dir: Path) -> Backend:
    """Where a sweep's learning processes run: one SLURM job array (files in ``out_dir/slurm``) with ``--slurm``,
    otherwise ``--jobs`` at a time on this machine."""
    return SlurmArray(out_dir / "slurm", slurm) if slurm.slurm else LocalProcesses(jobs)


def check_unused(out_dir: Path, command: str, force: bool) -> None:
    """A one-line error if ``out_dir`` holds results already and ``force`` was not given: a second run with the same
    ``--out`` would replace the first's without a word. A training run's folder is refused even with ``force``:
    ``force`` replaces a sweep's results, never a run's checkpoint, report or policy."""
    training = [name for name in run_files(out_dir) if name != RESULTS]
    if training:
        fail(
            command,
            f"--out {out_dir} holds a training run ({', '.join(training)}), which this would overwrite: "
            "give another --out",
        )
    if not force and (out_dir / RESULTS).exists():
        fail(
            command,
            f"--out {out_dir}: holds results already ({RESULTS}); give another --out, or --force to replace them",
        )


REPRODUCE = CommandHelp(
    "reproduce",
    "the paper's Figures 5 and 6: every method, 5 learning processes each, tables and a bar chart",
    "Runs random, local, A-CMOMMT and every learning method of the paper's Figure 5 (VQQL with 16 to 2048 "
    "codewords, local ENNC-QL, collaborative ENNC-QL options 1 and 2), 5 independent learning processes each, "
    "every process tested on the same 10 seeded 1000-step trials with 10 robots; writes results.md, results.json, "
    "figure5.png and every learned policy file into --out. --quick runs one process per method with a smaller "
    "budget.",
    (
        ("ennc-ql reproduce --quick", "a first look: one process per method, smaller budget"),
        ("ennc-ql reproduce --jobs 2", "the full run, two learning processes at a time"),
        ("ennc-ql reproduce --methods a-cmommt ennc-ql-collab-option2", "two methods only"),
    ),
    "--quick about 3 min; the full run about 1 h with --jobs 2 (2 cores)",
)


def add_reproduce_parser(sub: Any) -> None:
    p = add_command(sub, REPRODUCE)
    p.add_argument("--quick", action="store_true", help="reduced budget: 1 process per method, shorter learning")
    p.add_argument(
        "--processes", type=positive(int), help="learning processes per method (default: 5, or 1 with --quick)"
    )
    names = method_names()
    p.add_argument(
        "--methods",
        nargs="+",
        choices=names,
        metavar="METHOD",
        help=f"run only these (default: all): {', '.join(names)}",
    )
    p.add_argument(
        "--out", type=folder, metavar="DIR", help="output folder (default: runs/reproduce or runs/reproduce-quick)"
    )
    p.add_argument("--jobs", type=positive(int), default=1, help="learning processes run at once")
    p.add_argument("--force", action="store_true", help="replace the results already in --out")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_config_flags(p.add_argument_group("on a SLURM cluster (tools.slurm.array.ArrayConfig)"), ArrayConfig)
    p.set_defaults(func=cmd_reproduce)


def take_back(out_dir: Path, fresh: bool) -> None:
    """The output folder this command created, removed where a failure left it empty (a failed submission takes back
    its own files; a folder holding task logs or results is kept: the same command resubmits from it)."""
    if fresh and out_dir.is_dir() and not any(out_dir.iterdir()):
        out_dir.rmdir()


def cmd_reproduce(args: argparse.Namespace) -> int:
    budget = Budget.quick() if args.quick else Budget()
    processes = args.processes or (1 if args.quick else 5)
    out_dir = args.out or Path("runs") / ("reproduce-quick" if args.quick else "reproduce")
    check_folder(out_dir, "reproduce", "--out")
    check_unused(out_dir, "reproduce", args.force)
    fresh = not out_dir.exists()
    try:
        backend = sweep_backend(load_config(ArrayConfig, args=args), args.jobs, out_dir)
        report = reproduce(budget, processes, out_dir, args.methods or None, backend)
    except (ConfigError, SlurmError) as exc:
        take_back(out_dir, fresh)
        fail("reproduce", str(exc))
    report["output"] = str(out_dir)
    table = reproduce_table(report) + f"\nwritten to {out_dir}/ (results.md, results.json, figure5.png)"
    emit(report, args.json, table)
    return 0


ABLATE = CommandHelp(
    "ablate",
    "one learned method under parameter overrides (a sweep), K learning processes per variant, the same tests",
    "Runs one learned method under overrides of any field of its setup, named by dotted path: the budget "
    "(budget.phase2.alpha, budget.phase1.max_classes, ...), the scenario (scenario.action_steps, ...), the "
    "test-time rule of a robot that sees no target (lost_behaviour) and the formulation's parts (featurizer, reward, "
    "actions, trial_rules, act_every). Several values sweep a key and several --set sweep their product; every "
    "variant runs "
    "--processes learning processes, each tested on the same seeded trials, and each row carries A-CMOMMT, its "
    "oracle and the state-limited force laws on those trials. Writes results.md, results.json, ablation.png and "
    "every policy file into --out.",
    (
        ("ennc-ql ablate ennc-ql-collab-option2 --set budget.phase2.alpha=0.05,0.1 --quick", "two step sizes"),
        ("ennc-ql ablate ennc-ql-collab-option2 --set featurizer=collab6d,shared8d --jobs 2", "two states"),
    ),
    "about 20 s per learning process with --quick, about 3 min at the full budget (2 cores; reproduce's timings), "
    "times variants x --processes / --jobs",
)


def add_ablate_parser(sub: Any) -> None:
    p = add_command(sub, ABLATE)
    p.add_argument("method", choices=list(METHODS), metavar="METHOD", help=f"the learned method: {', '.join(METHODS)}")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=V1[,V2...]",
        help="override a field of the setup by dotted path (budget.phase2.alpha, budget.phase1.max_classes, "
        "scenario.action_steps, lost_behaviour, trial_rules, ...); several values sweep it, several --set sweep "
        "their product. The formulation's parts take: "
        + "; ".join(f"{part} {{{choices_help(part)}}}" for part in ("featurizer", "reward", "actions", "trial_rules"))
        + " (default: none, the method as configured)",
    )
    p.add_argument("--processes", type=positive(int), default=3, help="learning processes per variant")
    p.add_argument("--jobs", type=positive(int), default=1, help="learning processes run at once")
    p.add_argument("--quick", action="store_true", help="reproduce's reduced budget as the base")
    p.add_argument("--out", type=folder, metavar="DIR", help="output folder (default: runs/ablate-METHOD)")
    p.add_argument("--force", action="store_true", help="replace the results already in --out")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_config_flags(p.add_argument_group("on a SLURM cluster (tools.slurm.array.ArrayConfig)"), ArrayConfig)
    p.set_defaults(func=cmd_ablate)


def cmd_ablate(args: argparse.Namespace) -> int:
    out_dir = args.out or Path("runs") / f"ablate-{args.method}"
    try:
        sweep = parse_sets(args.set)
        check_used(args.method, sweep)
        base = Setup(budget=Budget.quick() if args.quick else Budget())
        for _, setup in variants(base, sweep):  # every combination checked before the first process starts
            setup.formulation(args.method)
        slurm: ArrayConfig = load_config(ArrayConfig, args=args)
    except ConfigError as exc:
        fail("ablate", str(exc))
    check_folder(out_dir, "ablate", "--out")
    check_unused(out_dir, "ablate", args.force)
    fresh = not out_dir.exists()
    try:
        report = ablate(args.method, sweep, base, args.processes, out_dir, sweep_backend(slurm, args.jobs, out_dir))
    except SlurmError as exc:
        take_back(out_dir, fresh)
        fail("ablate", str(exc))
    report["output"] = str(out_dir)
    emit(
        report, args.json, ablation_table(report) + f"\nwritten to {out_dir}/ (results.md, results.json, ablation.png)"
    )
    return 0
