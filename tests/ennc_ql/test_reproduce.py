"""A smoke run of ``reproduce`` on a tiny budget: every artefact is written and consistent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from algorithm.policy_file import load_policy
from ennc_ql.cli import main
from tests.fakes import TINY
from tools.sweeps.reproduce import reproduce


def test_tiny_reproduce_writes_consistent_results(tmp_path: Path) -> None:
    methods = ["random", "vqql-local-16", "ennc-ql-collab-option2"]
    report = reproduce(TINY, processes=2, out_dir=tmp_path, methods=methods)
    rows = {r["name"]: r for r in report["methods"]}
    assert list(rows) == methods
    assert rows["random"]["runs"] == 1 and rows["random"]["states"] is None
    assert rows["vqql-local-16"]["states"] == 16 and rows["vqql-local-16"]["runs"] == 2
    option2 = rows["ennc-ql-collab-option2"]
    assert option2["runs"] == 2 and option2["states"] >= 1
    assert option2["paper_coverage"] == 66.53
    for row in rows.values():
        per_run = np.asarray(row["coverage_per_run"])
        assert ((per_run >= 0) & (per_run <= 100)).all()
        assert row["coverage_mean"] == pytest.approx(per_run.mean(), abs=1e-3)
        assert all(len(trials) == TINY.test_trials for trials in row["coverage_per_trial"])
    assert json.loads((tmp_path / "results.json").read_text())["methods"] == report["methods"]
    table = (tmp_path / "results.md").read_text()
    assert all(f"| {name} |" in table for name in methods)
    assert (tmp_path / "figure5.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # Option 2 keeps one table per robot; the saved policy evaluates to the reported coverage.
    policy, header = load_policy(tmp_path / "policies" / "ennc-ql-collab-option2-1.npz")
    assert policy.tables.shape[0] == 10 and header["method"] == "ennc-ql-collab-option2"
    assert np.mean(header["prototypes_per_action"]) == pytest.approx(option2["states_per_run"][1], abs=0.01)


def test_eval_runs_a_saved_policy_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    reproduce(TINY, processes=1, out_dir=tmp_path, methods=["vqql-local-16"])
    path = tmp_path / "policies" / "vqql-local-16-0.npz"
    # reproduce tests on its budget's trials (seed 0, development trials): eval reads the same ones when told to.
    assert main(["eval", "--policy", str(path), "--trials", "2", "--steps", "120", "--seed", "0", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    report = json.loads((tmp_path / "results.json").read_text())
    assert out["method"] == "vqql-local-16" and out["prototypes_per_action"] == [16] * 8
    assert out["coverage_per_trial"] == pytest.approx(report["methods"][0]["coverage_per_trial"][0], abs=1e-3)


def test_eval_names_a_bad_policy_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"nope")
    for policy, message in (
        (bad, "not a policy file (not an .npz archive of plain arrays)"),
        (tmp_path / "missing.npz", "no such policy file"),
    ):
        with pytest.raises(SystemExit) as exc:
            main(["eval", "--policy", str(policy)])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and err.count("\n") == 1
        assert err.startswith(f"ennc-ql eval: error: --policy {policy}: {message}")
