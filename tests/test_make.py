"""The Makefile as a new user meets it: a bare ``make`` says what there is to make, and creates nothing."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_a_bare_make_prints_help_and_creates_nothing(tmp_path: Path) -> None:
    venv = tmp_path / "venv"  # where a first target that installed would create the environment
    # Run as a user would, not as a sub-make of `make test` (whose MAKELEVEL/MAKEFLAGS add "Entering directory").
    env = {k: v for k, v in os.environ.items() if k not in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS", "MAKEOVERRIDES")}
    done = subprocess.run(
        ["make", f"VENV={venv}"], cwd=REPO, env=env, capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("make run "), done.stdout
    for target in ("make run", "make test", f"make {venv}/.installed", "make lint", "make image-test", "make clean"):
        assert target in done.stdout
    assert not venv.exists() and done.stderr == ""
