"""The ``ennc-ql`` command line: thin subcommands over library functions, one module each.

Every subcommand that produces results accepts ``--json`` and then prints exactly one JSON object on stdout;
logs go to stderr. Bad input is one line, ``ennc-ql <command>: error: ...``, and exit status 2, before anything
starts (:mod:`ennc_ql.parser`).
"""

from __future__ import annotations

import argparse
import io
import logging
import os
import signal
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from ennc_ql.command import check_recording
from ennc_ql.parser import PROG, CommandParser, OutputError, add_commands, flush_out, wrap
from ennc_ql.router import add_router_parser
from tools.allocator import keep_freed_memory
from tools.system import die_with_parent

DESCRIPTION = """\
ENNC-QL reinforcement learning for cooperative multi-robot target observation (CMOMMT), as a distributed
actor-learner system: actor processes simulate robots and stream experience over Zenoh to one learner, which
broadcasts policies back; training is watched in the Rerun viewer."""

EPILOG = """\
first steps:
  ennc-ql eval --policy a-cmommt        # the hand-made reference on 10 test trials (about 1 s)
  ennc-ql up                            # the main job, as make run: 2 minutes of training (2 min 27 s in all)
  ennc-ql up --rerun spawn              # the same, watched live in the Rerun viewer
  ennc-ql COMMAND --help                # what a command does, with examples and its run time"""


def _version() -> str:
    try:
        return version(PROG)
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def build_parser(router_only: bool = False) -> argparse.ArgumentParser:
    """Every command's parser; ``router_only``: the router's alone, whose process never loads the simulator (the
    other commands' configurations import it, and with it numba's compiler: 40 MB of resident memory)."""
    parser = CommandParser(prog=PROG, description=wrap(DESCRIPTION), epilog=EPILOG)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr, and tracebacks")
    parser.add_argument("--version", action="version", version=f"{PROG} {_version()}")
    sub = add_commands(parser, dest="command")
    if router_only:
        add_router_parser(sub)
        return parser
    # Imported here, for the router's sake (above).
    from ennc_ql.actor import add_actor_parser
    from ennc_ql.bench import add_bench_parser
    from ennc_ql.chaos import add_chaos_parser
    from ennc_ql.evaluate import add_eval_parser
    from ennc_ql.learner import add_learner_parser
    from ennc_ql.secure import add_secure_parser
    from ennc_ql.slurm import add_slurm_parser
    from ennc_ql.sweeps import add_ablate_parser, add_reproduce_parser
    from ennc_ql.up import add_up_parser

    for add in (
        add_eval_parser,
        add_up_parser,
        add_learner_parser,
        add_actor_parser,
        add_router_parser,
        add_secure_parser,
        add_slurm_parser,
        add_chaos_parser,
        add_reproduce_parser,
        add_ablate_parser,
        add_bench_parser,
    ):
        add(sub)
    return parser


def _fill_closed_streams() -> None:
    """Standard streams closed at start (``ennc-ql eval >&-``): /dev/null in their place. Python leaves ``sys.stdout``
    None there, and the next file opened would take descriptor 1 and receive what the command prints."""
    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        try:
            os.fstat(fd)
        except OSError:
            opened = os.open(os.devnull, os.O_RDONLY if mode == "r" else os.O_WRONLY)
            if opened != fd:  # the lowest free descriptor: a lower one was closed too and is filled first
                os.dup2(opened, fd)
                os.close(opened)
        if getattr(sys, name) is None:
            setattr(sys, name, open(fd, mode, closefd=False))  # noqa: SIM115 - the process's own stream


def main(argv: Sequence[str] | None = None) -> int:
    _fill_closed_streams()
    die_with_parent()  # a child of ``up``: gone with it, whatever kills it
    for stream in (sys.stdout, sys.stderr):
        # Where the terminal's encoding lacks a character of ours (PYTHONIOENCODING=ascii, a C locale): a '?' in its
        # place, never a traceback.
        if isinstance(stream, io.TextIOWrapper):
            stream.reconfigure(errors="replace")
    try:
        try:
            return _main(argv)
        finally:
            flush_out()  # here, where a closed pipe or a full disk can still be answered, not at the interpreter's exit
    except BrokenPipeError:
        # The reader is gone (ennc-ql eval ... | head -1): nothing more to say to it. The shell's status of a
        # process ended by SIGPIPE, and nothing left for the interpreter to flush at exit.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 128 + signal.SIGPIPE
    except OutputError as exc:  # before a command ran (a help page, the version) or at the last flush
        return _output_failed(exc.prog or PROG, exc)


def _output_failed(prog: str, exc: OutputError) -> int:
    # Exit status 1, as coreutils answer ``> /dev/full``: the command's input was fine, the machine refused.
    print(f"{prog}: error: cannot write to standard output ({exc})", file=sys.stderr)
    return 1


def _main(argv: Sequence[str] | None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    # The command is the first word that is not a flag: the only options before it (-v, -h) take no value.
    command = next((w for w in words if not w.startswith("-")), None)
    args = build_parser(router_only=command == "router").parse_args(words)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    prog: str = args.prog
    resuming = bool(getattr(args, "resume", None))
    check_recording(getattr(args, "rerun", None), prog.removeprefix(PROG + " "), resuming=resuming)
    keep_freed_memory()  # every process of ours churns ~1 MB message buffers
    try:
        code: int = args.func(args)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        raise
    except OutputError as exc:
        return _output_failed(prog, exc)
    except Exception as exc:
        if args.verbose:
            raise
        # Not bad input (that was answered before anything started): a fault of ours, or of the machine.
        what = " ".join(f"{type(exc).__name__}: {exc}".split())
        print(f"{prog}: error: {what} (ennc-ql --verbose {command} ... shows the traceback)", file=sys.stderr)
        return 1
    return code


if __name__ == "__main__":
    sys.exit(main())
