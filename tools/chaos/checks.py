"""The reliability contract checked after a run, each check from figures of different processes
(:class:`Evidence`): the JSON object of the run (:func:`figures_and_checks`) and its table (:func:`results_table`)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import logging
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from learner.checkpoint import kept_visits
from tools.chaos.options import SECURE_ONLY
from tools.chaos.peers import POISON_TUPLES

log = logging.getLogger("tools.chaos")  # one name for the package: its lines read "tools.chaos: ..."

OVERSIZE_RISE_LIMIT_MB = 100.0
"""What the oversize put may add to the learner's or the router's RSS: the cap, not the 160 MiB, bounds it."""
MIN_LINK_BYTES_PER_TUPLE = 24
"""What the smallest formulation's tuple takes on the wire in arrays alone: two float32 states of 2 values (16 B), a
float32 reward, a uint8 action, an int16 robot and a bool done."""
RSS_GROWTH_FACTOR, RSS_MARGIN_MB = 2.0, 300.0
"""Bound on each process's RSS over the run: this factor times its RSS when the faults began, plus this margin.
A healthy process of any role stays well within it (its store and queues are bounded); a leak per message, per
reconnect or per restart over a soak does not."""


@dataclass(frozen=True, slots=True)
class Evidence:
    """What the checks read, each figure from the process that produced it."""

    actor_ids: list[str]
    report: dict[str, Any] | None
    """The learner's report.json (None: it wrote none)."""
    finals: dict[str, dict[str, Any] | None]
    """Each actor's final status, as its last incarnation printed it."""
    killed: dict[str, list[dict[str, int]]]
    """Each killed incarnation's last status, as chaos's observer saw it."""
    versions: list[int]
    """Policy versions in the order they arrived at chaos's observer."""
    restarts: list[dict[str, Any]]
    """Each learner-kill: versions published before it, the first after it (logged and seen)."""
    poison_id: str
    spoofed: int
    """Batches sent on a peer's own key claiming another actor's id."""
    records: list[dict[str, Any]]
    requested: tuple[str, ...]
    rss_samples: list[dict[str, float]]
    rss_baseline: dict[str, float]
    ended: dict[str, Any]
    """Each process: whether it was still running at the end, and its exit status after SIGTERM."""
    learner_id: str = "learner"
    relayed: dict[str, dict[str, int]] | None = None
    """With network faults: bytes each client's link relayed, ``up`` to the router and ``down`` from it."""


@dataclass(frozen=True, slots=True)
class Check:
    name: str
    ok: bool
    detail: str


def actor_figures(ev: Evidence) -> dict[str, dict[str, Any]]:
    """Per actor id: tuples stored (the learner), sent, acknowledged and held (its last incarnation), and the last
    seen acknowledged figures of its killed incarnations (the observer)."""
    stored = (ev.report or {}).get("tuples_by_actor", {})
    figures: dict[str, dict[str, Any]] = {}
    for actor in ev.actor_ids:
        final = ev.finals.get(actor) or {}
        killed = ev.killed.get(actor, [])
        figures[actor] = {
            "stored": stored.get(actor, 0),
            **{k: final.get(k) for k in ("tuples_sent", "tuples_acked", "visits_acked")},
            "held": final.get("outbox"),
            **{k: final.get(k) for k in ("resent", "rejected", "policy_version")},
            "killed_incarnations": len(killed),
            "killed_tuples_acked": sum(k["tuples_acked"] for k in killed),
            "killed_visits_acked": sum(k["visits_acked"] for k in killed),
        }
    return figures


def check_exactly_once(ev: Evidence, actors: dict[str, dict[str, Any]]) -> Check:
    name = "exactly once"
    if ev.report is None:
        return Check(name, False, "no learner report")
    problems = []
    for actor, a in actors.items():
        sent, acked, stored = a["tuples_sent"], a["tuples_acked"], a["stored"]
        if sent is None:
            problems.append(f"{actor}: no final status")
            continue
        if a["held"] != 0 or acked != sent:
            problems.append(f"{actor}: {acked} of {sent} tuples acknowledged, {a['held']} messages held")
        if a["killed_incarnations"]:
            floor = sent + a["killed_tuples_acked"]
            if stored < floor:
                problems.append(f"{actor}: {stored} stored < {floor} (sent by its last incarnation + acked to killed)")
        elif stored != sent:
            problems.append(f"{actor}: {stored} stored != {sent} sent")
    if ev.report["gaps"]:
        problems.append(f"{ev.report['gaps']} gaps")
    done = f"every tuple stored once (0 gaps, {ev.report['duplicates']} re-sent duplicates dropped)"
    return Check(name, not problems, "; ".join(problems) or done)


def visit_figures(ev: Evidence, actors: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """Visits in the learner's final tables (its last checkpoint) against those acknowledged to the actors."""
    figures: dict[str, Any] = {
        "acked": sum(a["visits_acked"] or 0 for a in actors.values()),
        "killed_acked": sum(a["killed_visits_acked"] for a in actors.values()),
        "in_tables": None,
        "dropped": None,
    }
    path = (ev.report or {}).get("checkpoint")
    if path:
        try:
            figures["in_tables"], figures["dropped"] = kept_visits(Path(path))
        except (OSError, ValueError, zipfile.BadZipFile) as exc:
            log.error("cannot read the final checkpoint %s: %s", path, exc)
    return figures


def check_visits(ev: Evidence, visits: dict[str, Any]) -> Check:
    """Every acknowledged increment applied to the tables the learner holds, none stale."""
    name = "acknowledged visits applied"
    in_tables, dropped = visits["in_tables"], visits["dropped"]
    acked, killed = visits["acked"], visits["killed_acked"]
    if in_tables is None:
        return Check(name, False, "no readable final checkpoint")
    if ev.killed:  # a killed incarnation's last acknowledgements were never seen: a lower bound only
        ok, relation = in_tables >= acked + killed, f">= {acked} + {killed} acked to killed incarnations"
    else:
        ok, relation = in_tables == acked, f"== {acked} acknowledged"
    return Check(
        name,
        ok and dropped == 0 and acked > 0,
        f"{in_tables} visits applied to the final tables {relation}; {dropped} in stale increments",
    )


def check_versions(ev: Evidence) -> Check:
    seen = ev.versions
    increasing = all(b > a for a, b in itertools.pairwise(seen))
    jumps = [
        f"{r['published_before']} -> {r['first_version_logged']} (seen {r['first_version_seen']})" for r in ev.restarts
    ]
    after = all(min(r["first_version_logged"], r["first_version_seen"]) > r["published_before"] for r in ev.restarts)
    shown = f"{len(seen)} seen, v{seen[0]}..v{seen[-1]}" if seen else "none seen"
    detail = f"{shown}, {'strictly increasing' if increasing else 'NOT strictly increasing'}"
    if jumps:
        detail += f"; published before a kill -> first after: {', '.join(jumps)}"
    return Check("policy versions", bool(seen) and increasing and after, detail)


def check_poison(ev: Evidence) -> Check | None:
    rounds = [r for r in ev.records if r["name"] == "poison"]
    if not rounds:
        return None
    flowed = sum(r.get("rejected_seqs") == [1] and r.get("acked_seq", -1) >= 2 for r in rounds)
    stored = (ev.report or {}).get("tuples_by_actor", {}).get(ev.poison_id, 0)
    expected = 2 * POISON_TUPLES * len(rounds)
    detail = (
        f"{flowed} of {len(rounds)} rounds: Reject of seq 1 and ack of seq 2; "
        f"{stored} tuples stored for {ev.poison_id} (expected {expected})"
    )
    return Check("poisoned stream flows on", flowed == len(rounds) and stored == expected, detail)


def check_hostile(ev: Evidence) -> Check | None:
    refusals = [r for r in ev.records if r["name"] in SECURE_ONLY]
    if not refusals and not ev.spoofed and not any(r["name"] == "oversize" for r in ev.records):
        return None
    if ev.report is None:
        return Check("nothing from hostile peers", False, "no learner report")
    report = ev.report
    allowed = set(ev.actor_ids) | ({ev.poison_id} if any(r["name"] == "poison" for r in ev.records) else set())
    strangers = {k: v for k, v in report.get("tuples_by_actor", {}).items() if k not in allowed}
    lies = report.get("rejected_by_type", {}).get("IdentityMismatch", 0)
    problems = [f"stored from {who}: {n} tuples" for who, n in strangers.items()]
    if lies != ev.spoofed:
        problems.append(f"{lies} IdentityMismatch rejections for {ev.spoofed} lies")
    refused = sum(bool(r.get("refused")) for r in refusals)  # one that opened is caught above if it stored anything
    done = f"0 tuples stored from them, {lies} lies rejected" + (
        f", {refused} of {len(refusals)} sessions refused" if refusals else ""
    )
    return Check("nothing from hostile peers", not problems, "; ".join(problems) or done)


def rss_bounds(ev: Evidence) -> dict[str, float]:
    return {name: round(RSS_GROWTH_FACTOR * mb + RSS_MARGIN_MB) for name, mb in ev.rss_baseline.items()}


def check_rss(ev: Evidence, peaks: dict[str, float]) -> Check:
    bounds = rss_bounds(ev)
    problems = [f"{n} {peaks[n]:.0f} MB > {bound:.0f} MB" for n, bound in bounds.items() if peaks.get(n, 0) > bound]
    for r in ev.records:
        if r["name"] == "oversize":
            big = {n: mb for n, mb in r.get("rss_rise_mb", {}).items() if mb >= OVERSIZE_RISE_LIMIT_MB}
            problems += [f"{n} rose {mb:.0f} MB on the oversize put at t={r['t_s']:.0f}s" for n, mb in big.items()]
    if not bounds:
        problems.append("no RSS baseline (the faults never began)")
    shown = ", ".join(f"{n} {mb:.0f}" for n, mb in peaks.items())
    return Check("RSS bounded", not problems, "; ".join(problems) or f"max MB: {shown}")


def check_faults(ev: Evidence) -> Check:
    applied = {r["name"] for r in ev.records}
    problems = [f"{name} never applied" for name in ev.requested if name not in applied]
    problems += [
        f"{r['name']} at t={r['t_s']:.0f}s: {r.get('error', 'not as expected')}" for r in ev.records if not r["ok"]
    ]
    done = f"{len(ev.records)} applied ({', '.join(dict.fromkeys(r['name'] for r in ev.records))}), every one held"
    return Check("faults held", not problems, "; ".join(problems) or done)


def check_links(ev: Evidence) -> Check | None:
    """With network faults, the experience crossed the emulated links: each actor's link carried up, and the
    learner's down, at least MIN_LINK_BYTES_PER_TUPLE per tuple stored (shared memory, which the hosts' common
    /dev/shm would allow, would have carried it past them)."""
    if ev.relayed is None:
        return None
    stored = (ev.report or {}).get("tuples_by_actor", {})
    floors = {actor: MIN_LINK_BYTES_PER_TUPLE * stored.get(actor, 0) for actor in ev.actor_ids}
    problems = [
        f"{actor}'s link carried {ev.relayed[actor]['up']} B up < {floor} B"
        for actor, floor in floors.items()
        if ev.relayed[actor]["up"] < floor
    ]
    down, floor = ev.relayed[ev.learner_id]["down"], sum(floors.values())
    if down < floor:
        problems.append(f"the learner's link carried {down} B down < {floor} B")
    shown = ", ".join(
        f"{name} {d['up'] / 1e6:.1f} MB up / {d['down'] / 1e6:.1f} MB down" for name, d in ev.relayed.items()
    )
    return Check("traffic on the links", not problems and bool(floors), "; ".join(problems) or shown)


def check_processes(ev: Evidence) -> Check:
    problems = [
        f"{name} {'had exited before the end' if not e['running'] else 'exited with status ' + str(e.get('code'))}"
        for name, e in ev.ended.items()
        if not e["running"] or e.get("code") != 0
    ]
    return Check("processes", not problems, "; ".join(problems) or "every process ran to the end and exited 0")


def figures_and_checks(ev: Evidence, summary: dict[str, Any]) -> dict[str, Any]:
    """The JSON object of a run: its figures and every check of the contract."""
    actors = actor_figures(ev)
    visits = visit_figures(ev, actors)
    peaks = max_rss(ev.rss_samples)
    checks = [
        check_faults(ev),
        check_processes(ev),
        check_exactly_once(ev, actors),
        check_visits(ev, visits),
        check_versions(ev),
        check_poison(ev),
        check_hostile(ev),
        check_rss(ev, peaks),
        check_links(ev),
    ]
    held = [c for c in checks if c is not None]
    report = ev.report or {}
    learner_keys = (
        *("tuples_received", "tuples_by_actor", "duplicates", "gaps", "rejected", "rejected_by_type"),
        *("stale_increments", "policy_version", "final_coverage_mean", "policy_file"),
    )
    return {
        **summary,
        "passed": all(c.ok for c in held),
        "failed": [c.name for c in held if not c.ok],
        "checks": [dataclasses.asdict(c) for c in held],
        "faults": ev.records,
        "actors": actors,
        "visits": visits,
        "versions": {"seen": ev.versions, "restarts": ev.restarts},
        "learner": {k: report.get(k) for k in learner_keys},
        "processes": ev.ended,
        "links": ev.relayed,
        "rss": {"samples": ev.rss_samples, "baseline_mb": ev.rss_baseline, "max_mb": peaks, "bound_mb": rss_bounds(ev)},
    }


def max_rss(samples: list[dict[str, float]]) -> dict[str, float]:
    peaks: dict[str, float] = {}
    for sample in samples:
        for name, mb in sample.items():
            if name != "t":
                peaks[name] = max(peaks.get(name, 0.0), mb)
    return peaks


# -- the table --------------------------------------------------------------------------------------------------------


def _fault_line(record: dict[str, Any]) -> str:
    shown = {k: v for k, v in record.items() if k not in ("name", "t_s", "ok")}
    figures = ", ".join(f"{k} {v if isinstance(v, str | int | float) else json.dumps(v)}" for k, v in shown.items())
    return f"  t={record['t_s']:>5.0f}s  {record['name']:<17} {'held' if record['ok'] else 'FAILED':<6}  {figures}"


def results_table(out: dict[str, Any]) -> str:
    verdict = "PASSED" if out["passed"] else f"FAILED ({', '.join(out['failed'])})"
    mode = "secure" if out["secure"] else "plain"
    lines = [f"chaos {out['run_id']} ({mode}, {len(out['faults'])} faults in {out['wall_s']:.0f} s): {verdict}"]
    lines += [f"  {'PASS' if c['ok'] else 'FAIL'}  {c['name']:<26} {c['detail']}" for c in out["checks"]]
    lines += ["", f"  {'actor':<12}{'stored':>10}{'sent':>10}{'acked':>10}{'visits acked':>14}{'held':>6}  killed"]
    for actor, a in out["actors"].items():
        killed = f"{a['killed_incarnations']} (acked {a['killed_tuples_acked']})" if a["killed_incarnations"] else "-"
        lines.append(
            f"  {actor:<12}{a['stored']:>10}{a['tuples_sent']!s:>10}{a['tuples_acked']!s:>10}"
            f"{a['visits_acked']!s:>14}{a['held']!s:>6}  {killed}"
        )
    lines += ["", "faults", *map(_fault_line, out["faults"])]
    lines += [f"  skipped {name}: {why}" for name, why in out.get("skipped", {}).items()]
    rejected = out["learner"]["rejected_by_type"] or {}
    lines += ["", f"rejected by class: {', '.join(f'{k} {v}' for k, v in rejected.items()) or 'none'}"]
    lines.append(f"RSS max (MB): {', '.join(f'{k} {v:.0f}' for k, v in out['rss']['max_mb'].items())}")
    lines.append(f"figures: {out['run_dir']}/chaos.json")
    return "\n".join(lines)
