"""``ennc-ql secure init`` as a command: one-line errors, and a second run that keeps the CA but replaces every
identity's key and password (so a leaked password is revoked by running it again)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from ennc_ql.cli import main


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--actors", "0"], "--actors: expected a positive integer of at most 10000"),
        (["--namespace", "a b"], "namespace chunk"),
    ],
)
def test_bad_flags_are_one_line_errors(flags: list[str], message: str, tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "ennc_ql.cli", "secure", "init", str(tmp_path / "s"), *flags],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) <= 2 and lines[0].startswith("ennc-ql secure init: error:") and message in lines[0]
    assert lines[1:] in ([], ["usage: ennc-ql secure init [OPTIONS] DIR  (all options: ennc-ql secure init --help)"])
    assert not (tmp_path / "s").exists()


def test_a_second_run_keeps_the_ca_and_replaces_keys_and_passwords(tmp_path: Path) -> None:
    folder = tmp_path / "s"
    assert main(["secure", "init", str(folder), "--actors", "1"]) == 0
    first = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert main(["secure", "init", str(folder), "--actors", "3"]) == 0
    second = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert second["ca.pem"] == first["ca.pem"] and second["ca.key"] == first["ca.key"]
    for name in ("actor-0.key", "learner.key", "credentials.txt", "actor-0.json5"):
        assert second[name] != first[name]
    assert {"actor-1.json5", "actor-2.key"} <= set(second)
    users = [line.split(":")[0] for line in second["credentials.txt"].decode().splitlines()]
    assert users == ["learner", "actor-0", "actor-1", "actor-2", "observer"]


def test_every_configuration_keeps_payloads_inside_tls(tmp_path: Path) -> None:
    """Shared memory would hand a same-host peer its payloads outside the encrypted link: off in every file."""
    folder = tmp_path / "s"
    assert main(["secure", "init", str(folder), "--actors", "2"]) == 0
    files = sorted(folder.glob("*.json5"))
    assert [p.stem for p in files] == ["actor-0", "actor-1", "learner", "observer", "router"]
    for path in files:
        conf = zenoh.Config.from_file(str(path))
        assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False, path.name
        assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True, path.name


@pytest.mark.parametrize(
    "argv",
    [["router"], ["learner", "--run-dir", "RUN"], ["actor", "--actor-id", "actor-0"]],
    ids=["router", "learner", "actor"],
)
def test_a_configuration_the_process_cannot_read_is_a_one_line_error_naming_it(argv: list[str], tmp_path: Path) -> None:
    """What a container prints when its mounted secrets are not readable by its user (the image runs as uid 1000)."""
    missing = tmp_path / "secrets" / "actor-0.json5"
    argv = [str(tmp_path / "run") if a == "RUN" else a for a in argv]
    out = subprocess.run(
        [sys.executable, "-m", "ennc_ql.cli", *argv, "--zenoh-config", str(missing)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert lines == [f"ennc-ql {argv[0]}: error: --zenoh-config {missing}: no such file"], out.stderr
