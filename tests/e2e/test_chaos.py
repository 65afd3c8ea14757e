"""End-to-end: ``ennc-ql chaos --secure`` starts a real cluster (router, learner, two actors), applies every fault
once while it trains, and checks the reliability contract from outside. Where network namespaces can be made (root,
iproute2, iptables: CI) every process runs on a host of its own and the network faults (partition, delay, loss)
are among them; elsewhere chaos skips those, saying why.

Asserted on the raw figures, each against another process's (the learner's report.json and policy file, each actor
incarnation's final status file, chaos's observer): tuples exactly once per actor, every acknowledged visit in the
final tables, policy versions strictly increasing across learner restarts, the poisoned stream flowing on, nothing
stored from hostile peers, the unauthenticated and wrong-certificate sessions refused, RSS bounded, every fault
applied; and no process of the run is left behind. Configuration errors are one line and exit 2.
"""

from __future__ import annotations

import itertools
import json
import re
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pytest

from algorithm.policy_file import load_policy
from learner.checkpoint import kept_visits
from tests import system
from tests.e2e import ACTOR_PACE, ennc_ql
from tools.chaos import FAULTS
from tools.chaos.network import PREFIX, unavailable
from tools.chaos.options import NETWORK_FAULTS

pytestmark = pytest.mark.slow

NETWORK = unavailable()
"""Why the network faults cannot run here, or None (they run)."""

# Borrowed from test_cluster.FAST_LEARNER: a first policy within seconds; checkpoints (and acks) every 2 s.
FAST = [
    *("--learner-min-tuples", "20000", "--learner-phase1-max-patterns", "1500", "--learner-phase1-n-cycles", "30"),
    *("--learner-phase1-seed-prototypes", "32", "--learner-phase1-max-iterations", "1"),  # a first fit in seconds
    *("--learner-broadcast-interval", "1", "--learner-checkpoint-interval", "2", "--learner-eval-interval", "1000"),
    *("--learner-eval-trials", "2", "--learner-final-eval-trials", "2", "--actor-arenas", "32"),
    *("--actor-max-tuples-per-s", ACTOR_PACE),
    *("--actor-flush-timeout", "30"),  # the last acks come after the learner's next checkpoint, on loaded cores
]
# One round of the nine process faults takes about a minute at one every 5 s (actor-stop alone 10-15 s); the
# network faults add about 40 s (a partition past the lease, two 8 s windows of delay and loss).
TIMING = ["--duration", "60", "--fault-interval", "5", "--rss-interval", "5"]


def run_watching_descendants(
    argv: list[str], out: Path, err: Path, timeout: float
) -> tuple[int, list[psutil.Process], int]:
    """Run ``argv`` to its end, noting every descendant process it had meanwhile (they cannot be listed once it
    exited: orphans are re-parented); its exit status, those processes and its pid. Everything is killed on a
    timeout."""
    seen: dict[int, psutil.Process] = {}
    with open(out, "wb") as stdout, open(err, "wb") as stderr:
        proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=stdout, stderr=stderr)
    deadline = time.monotonic() + timeout
    try:
        while proc.poll() is None and time.monotonic() < deadline:
            try:
                for child in psutil.Process(proc.pid).children(recursive=True):
                    seen.setdefault(child.pid, child)
            except psutil.NoSuchProcess:
                pass  # it just exited
            time.sleep(0.5)
        timed_out = proc.poll() is None
    finally:
        if proc.poll() is None:  # timed out, or the test was interrupted: leave nothing behind
            for p in [psutil.Process(proc.pid), *seen.values()]:
                if alive(p):
                    p.kill()
            proc.wait()
    assert not timed_out, f"chaos still running after {timeout:.0f} s; its log ends:\n{tail(err)}"
    return proc.returncode, list(seen.values()), proc.pid


def tail(path: Path, lines: int = 40) -> str:
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])


def final_status(run_dir: Path, actor: str) -> dict[str, Any]:
    """What the actor's last incarnation printed as it stopped (``RUN/<id>.<k>.out``)."""
    files = sorted(run_dir.glob(f"{actor}.*.out"), key=lambda p: int(p.name.split(".")[-2]))
    status: dict[str, Any] = json.loads(files[-1].read_text().strip().splitlines()[-1])
    return status


def alive(p: psutil.Process) -> bool:
    try:
        return p.is_running() and p.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


Faults = dict[str, list[dict[str, Any]]]
"""The records of the faults applied, by name."""


def run_chaos(tmp_path: Path) -> tuple[dict[str, Any], Path, str]:
    """``ennc-ql chaos --secure --json`` to its end: the JSON object it printed, its run folder and its log; no
    process of the run is left behind, nor any network namespace of it."""
    argv = ennc_ql("chaos", "--secure", "--json", "--runs", str(tmp_path), "--run-id", "e2e", *TIMING, *FAST)
    out_file, err_file = tmp_path / "chaos.out", tmp_path / "chaos.log"
    code, descendants, pid = run_watching_descendants(argv, out_file, err_file, timeout=900)
    assert not [p.pid for p in descendants if alive(p)]
    if NETWORK is None:
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True, check=True).stdout
        assert f"{PREFIX}-{pid}-" not in listed, listed
    lines = out_file.read_text().splitlines()
    assert len(lines) == 1, f"stdout is not exactly one JSON object:\n{out_file.read_text()[:2000]}"
    out: dict[str, Any] = json.loads(lines[0])
    assert code == 0 and out["passed"], f"failed: {out['failed']}\n{tail(err_file)}"
    run_dir = tmp_path / "e2e"
    assert json.loads((run_dir / "chaos.json").read_text()) == out
    # Every incarnation of every process was seen running (and is gone, above).
    restarts = sum(f["name"] in ("router-restart", "learner-kill", "actor-kill") for f in out["faults"])
    assert len(descendants) >= 4 + restarts
    return out, run_dir, err_file.read_text()


def assert_exactly_once(run_dir: Path, report: dict[str, Any], out: dict[str, Any], faults: Faults) -> None:
    """From three processes: the learner's report, each actor's final status, chaos's observer (the last status of a
    killed incarnation: what it had seen acknowledged, a lower bound of what it had stored). And every acknowledged
    increment's visits are applied to the tables the learner holds at the end, and none is stale: no fit replaced
    the tables under the actors."""
    assert report["gaps"] == 0 and report["stale_increments"] == 0 and report["phase1_fits"] == 1
    killed: dict[str, dict[str, int]] = {}
    for kill in faults["actor-kill"]:
        for k, n in kill["last_seen"].items():
            killed.setdefault(kill["actor"], {}).setdefault(k, 0)
            killed[kill["actor"]][k] += n
    assert killed and "actor-0" not in killed  # the spoofed id keeps an exact count
    finals = {actor: final_status(run_dir, actor) for actor in ("actor-0", "actor-1")}
    for actor, final in finals.items():
        assert final["outbox"] == 0 and final["tuples_sent"] == final["tuples_acked"] > 0
        stored = report["tuples_by_actor"][actor]
        if actor in killed:
            assert stored >= final["tuples_sent"] + killed[actor]["tuples_acked"]
        else:
            assert stored == final["tuples_sent"]
        assert out["actors"][actor]["stored"] == stored and out["actors"][actor]["tuples_sent"] == final["tuples_sent"]
    # Read from the final checkpoint, and from the policy file: the saved tables are the last ones, so they hold
    # every visit the checkpoint's tables hold (a team policy: the robots' rows merged by their visits).
    in_tables, dropped = kept_visits(Path(report["checkpoint"]))
    with np.load(report["checkpoint"]) as checkpoint:
        held = int(checkpoint["visits"].astype(np.int64).sum())
    saved, _ = load_policy(report["policy_file"])
    assert saved.version == report["saved"]["version"] == report["policy_version"]
    acked = sum(f["visits_acked"] for f in finals.values()) + sum(k["visits_acked"] for k in killed.values())
    assert dropped == 0
    assert in_tables >= acked > 0  # a killed incarnation's: a lower bound only
    assert in_tables == held  # nothing pending after the final merge, nothing carried (no refit)


def assert_versions(run_dir: Path, out: dict[str, Any], faults: Faults) -> None:
    """Strictly increasing on the wire; each resumed learner starts above every version the killed one sent."""
    seen = out["versions"]["seen"]
    assert len(seen) > 10 and all(b > a for a, b in itertools.pairwise(seen))
    log = (run_dir / "learner.log").read_text()
    started = [int(v) for v in re.findall(r"started \(policy version (\d+)\)", log)]
    assert started[0] == 0 and len(started) == len(faults["learner-kill"]) + 1
    for kill, first in zip(faults["learner-kill"], started[1:], strict=True):
        assert first == kill["first_version_logged"] > kill["published_before"] > 0
        assert kill["first_version_seen"] > kill["published_before"] and kill["first_version_seen"] in seen


def assert_hostile_peers_failed(report: dict[str, Any], faults: Faults) -> None:
    """The poisoned stream flows on; the lies are counted and dropped; the refused sessions stored nothing."""
    poison = faults["poison"]
    assert all(p["rejected_seqs"] == [1] and p["acked_seq"] >= 2 for p in poison)
    assert report["tuples_by_actor"]["mallory"] == 2 * 5 * len(poison)  # seq 0 and 2 of each round, 5 tuples each
    assert report["rejected_by_type"]["InvalidValues"] == len(poison)
    assert set(report["tuples_by_actor"]) == {"actor-0", "actor-1", "mallory"}
    assert report["rejected_by_type"]["IdentityMismatch"] == 3 * len(faults["spoof"])
    assert all(s["puts_on_claimed_key"] == 3 for s in faults["spoof"])  # dropped by the router's access control
    for name in ("unauthenticated", "wrong-certificate"):
        assert all(f["refused"] and f["control_opened"] for f in faults[name]), faults[name]


def assert_rss_bounded(out: dict[str, Any], log: str, faults: Faults) -> None:
    """Sampled throughout, each sample one log line; every process far from runaway; the oversize put (dropped
    while zenoh reassembled it) barely moves the learner or the router."""
    samples = out["rss"]["samples"]
    assert len(samples) >= 5 and len(re.findall(r"chaos: t=\d+s \S+ \d+ MB", log)) == len(samples)
    assert re.search(r"t=\d+s router \d+ MB, learner \d+ MB, actor-0 \d+ MB, actor-1 \d+ MB", log)
    peaks = out["rss"]["max_mb"]
    assert peaks["router"] < 1000 and peaks["learner"] < 3000 and max(peaks["actor-0"], peaks["actor-1"]) < 1500
    for oversize in faults["oversize"]:
        assert oversize["learner_up"] and max(oversize["rss_rise_mb"].values()) < 100


def assert_network_faults_held(out: dict[str, Any], report: dict[str, Any], faults: Faults) -> None:
    """The partitioned actor was counted gone, then back, and its acknowledgements moved again; the streams kept
    flowing through the delayed and the lossy links; and the experience crossed the links (no shared memory)."""
    assert sorted(out["hosts"]) == sorted(["router", "learner", "actor-0", "actor-1"])
    for cut in faults["partition"]:
        assert cut["live_actors_min"] < 2 and cut["partitioned_s"] >= 10  # past the zenoh lease
        assert cut["gone_after_s"] <= cut["partitioned_s"] and cut["recovered_s"] >= 0 and cut["acks_resumed_s"] >= 0
    for shaped in (*faults["delay"], *faults["loss"]):
        assert all(n > 0 for n in shaped["tuples_acked_during"].values()) and shaped["live_actors_min"] == 2
        assert shaped["relayed_mb_during"] > 0
    assert faults["delay"][0]["delay_ms_each_way"] > 0 and faults["loss"][0]["loss_per_chunk"] > 0
    links = out["links"]
    for actor in ("actor-0", "actor-1"):  # at least 24 bytes of arrays per tuple, each way of the store
        assert links[actor]["up"] >= 24 * report["tuples_by_actor"][actor]
    assert links["learner"]["down"] >= 24 * report["tuples_received"]
    assert next(c for c in out["checks"] if c["name"] == "traffic on the links")["ok"]


def test_chaos_applies_every_fault_and_the_contract_holds(tmp_path: Path) -> None:
    # Where the network faults must run (CI installs iptables), their absence is a failure, not a skipped fault.
    assert not (system.required(system.NETNS) and NETWORK), f"{NETWORK}, but {system.variable(system.NETNS)}=1"
    out, run_dir, log = run_chaos(tmp_path)
    faults: Faults = {name: [f for f in out["faults"] if f["name"] == name] for name in FAULTS}
    expected = [name for name in FAULTS if NETWORK is None or name not in NETWORK_FAULTS]
    assert all(faults[name] for name in expected) and all(f["ok"] for f in out["faults"]), out["faults"]
    assert out["skipped"] == ({} if NETWORK is None else {f: NETWORK for f in FAULTS if f in NETWORK_FAULTS})
    report = json.loads((run_dir / "report.json").read_text())
    assert_exactly_once(run_dir, report, out, faults)
    assert_versions(run_dir, out, faults)
    assert_hostile_peers_failed(report, faults)
    for stop in faults["actor-stop"]:  # counted gone after the lease, back once continued
        assert stop["live_actors_min"] < 2 and stop["recovered_s"] >= 0
    assert_rss_bounded(out, log, faults)
    if NETWORK is None:
        assert_network_faults_held(out, report, faults)


@pytest.mark.parametrize(
    ("flags", "bad"),
    [(["--faults", "learner-kill,meteor-strike"], "meteor-strike"), (["--soak", "3fortnights"], "3fortnights")],
)
def test_a_bad_fault_name_or_soak_value_is_a_one_line_error(tmp_path: Path, flags: list[str], bad: str) -> None:
    result = subprocess.run(
        ennc_ql("chaos", "--runs", str(tmp_path), *flags), capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ennc-ql chaos: error:") and bad in lines[0], result.stderr
    assert not list(tmp_path.iterdir())  # nothing started, nothing written
