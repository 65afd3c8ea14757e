"""The SLURM client commands this package runs, and how sbatch options are given::

job_id = submit(script, "--array=0-3")        # sbatch --parsable ...
text = slurm_command(["squeue", "--noheader", "--jobs=17"])
"""

from __future__ import annotations

import shlex
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any


class SlurmError(RuntimeError):
    """Not inside a SLURM job, or a SLURM command failed (the message says which and why)."""


def slurm_command(argv: Sequence[str], timeout: float = 60.0) -> str:
    """The stdout of a SLURM client command; :class:`SlurmError` with its stderr if it fails."""
    try:
        done = subprocess.run(list(argv), capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SlurmError(f"{shlex.join(argv)}: {exc}") from None
    if done.returncode != 0:
        # One line: an error of ours is one line, and sbatch's own run over several.
        said = "; ".join(line.strip() for line in done.stderr.splitlines() if line.strip())
        raise SlurmError(f"{shlex.join(argv)} failed: {said or f'exit status {done.returncode}'}")
    return done.stdout


def submit(script: Path, *options: str) -> str:
    """``sbatch`` the script with ``options``; the job id."""
    return slurm_command(["sbatch", "--parsable", *options, str(script)]).strip().split(";")[0]


def _sbatch_options(text: str) -> tuple[str, ...]:
    options = tuple(shlex.split(text))
    bad = [o for o in options if not o.startswith("-")]
    if bad:
        raise ValueError(f"expected sbatch options such as --mem=8G, got {' '.join(bad)!r}")
    return options


SBATCH_FIELD: dict[str, Any] = {"parse": _sbatch_options, "format": shlex.join, "metavar": "'OPTIONS'"}
"""The metadata of a configuration field holding sbatch options, given as one string (split as a shell would)."""
