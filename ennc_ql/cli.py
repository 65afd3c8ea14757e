"""The ``ennc-ql`` command line: thin subcommands over library functions, one module each.

Every subcommand that produces results accepts ``--json`` and then prints exactly one JSON object on stdout;
logs go to stderr.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

from ennc_ql.allocator import keep_freed_memory
from ennc_ql.router import add_router_parser


def build_parser(router_only: bool = False) -> argparse.ArgumentParser:
    """Every command's parser; ``router_only``: the router's alone, whose process never loads the simulator (the
    other commands' configurations import it, and with it numba's compiler: 40 MB of resident memory)."""
    parser = argparse.ArgumentParser(prog="ennc-ql", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging on stderr")
    sub = parser.add_subparsers(dest="command", required=True)
    if router_only:
        add_router_parser(sub)
        return parser
    # Imported here, for the router's sake (above).
    from ennc_ql.actor import add_actor_parser
    from ennc_ql.bench.command import add_bench_parser
    from ennc_ql.chaos import add_chaos_parser
    from ennc_ql.evaluate import add_eval_parser
    from ennc_ql.experiments.ablate import add_ablate_parser
    from ennc_ql.experiments.reproduce import add_reproduce_parser
    from ennc_ql.learner import add_learner_parser
    from ennc_ql.secure import add_secure_parser
    from ennc_ql.slurm.command import add_slurm_parser
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


def main(argv: Sequence[str] | None = None) -> int:
    words = list(sys.argv[1:] if argv is None else argv)
    # The command is the first word that is not a flag: the only options before it (-v, -h) take no value.
    command = next((w for w in words if not w.startswith("-")), None)
    args = build_parser(router_only=command == "router").parse_args(words)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    keep_freed_memory()  # every process of ours churns ~1 MB message buffers
    code: int = args.func(args)
    return code


if __name__ == "__main__":
    sys.exit(main())
