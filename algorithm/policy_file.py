"""The portable policy file: one ``.npz`` archive (a zip of ``.npy`` arrays) with a JSON header.

Layout (format ``ennc-ql-policy``, version 1; see docs/reference/policy-file.md):

============  ================  ============================================================
member        dtype / shape     content
============  ================  ============================================================
header        uint8 (B,)        UTF-8 JSON: format, version, scenario, featurizer, actions...
prototypes    float32 (P, d)    per-action prototypes, concatenated (P = Σ_a P_a)
labels        float32 (P,)      phase-1 Q value of each prototype
offsets       int64 (L+1,)      action a owns rows offsets[a]:offsets[a+1]
tables        float32 (R, P)    Q tables, one row per table
robot_table   int64 (m,)        table row used by robot i
visits        uint64 (R, P)     visit counts (optional)
scale         float32 (d,)      per-dimension metric scale (optional; absent = Euclidean)
============  ================  ============================================================

Usage::

    save_policy(policy, cfg, "runs/x/policy.npz")
    policy, header = load_policy("runs/x/policy.npz")
"""

from __future__ import annotations

import dataclasses
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from algorithm.discretization import Discretization
from algorithm.files import save_npz_atomic
from algorithm.policy import Policy
from sim import ScenarioConfig
from sim.actions import ActionSet
from sim.formulation import Formulation

FRAMES = {
    "world": "world (x east, y north), target/robot position minus own position",
    "target": "target (x towards the nearest target in view, y towards the furthest target's side), see the "
    "policy file's documentation",
}
"""The header's description of each featurizer frame (informative)."""

FORMAT = "ennc-ql-policy"
FORMAT_VERSION = 1


class PolicyFileError(ValueError):
    """The file is not a readable policy file of a supported version."""


def header_for(policy: Policy, cfg: ScenarioConfig) -> dict[str, Any]:
    formulation = policy.formulation
    moves, state = formulation.actions, formulation.featurizer
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "method": policy.method,
        "version": policy.version,
        "scenario": dataclasses.asdict(cfg),
        "featurizer": {
            "name": state.name,
            "dim": state.dim,
            "state": list(state.state),
            "frame": FRAMES[state.frame],
            "mask_value": cfg.mask_value,
            "local_target": cfg.local_target,
        },
        "action_set": _action_set(moves),
        "actions": [
            {"index": i, "name": name, "direction": [float(v) for v in moves.directions[i]]}
            for i, name in enumerate(moves.moves)
        ],
        "reward": {"name": formulation.reward.name, "per_decision": formulation.reward.per_decision},
        "action_steps": policy.action_steps,
        "action_mode": policy.action_mode,
        "max_action_steps": policy.max_action_steps,
        "lost_behaviour": policy.lost_behaviour,
        "law_margin": policy.law_margin,
        "prototypes_per_action": [int(s) for s in policy.discretization.sizes()],
        "meta": policy.meta,
    }


def _action_set(moves: ActionSet) -> dict[str, Any]:
    """The header's ``action_set``: the frame the moves are named in, and the law whose pull a law frame follows."""
    if moves.law is None:
        return {"name": moves.name, "frame": "target" if moves.relative else "world"}
    law = moves.law
    fields = ("do1", "do2", "do3", "do4", "dr1", "dr2", "shared_target_weight")
    frame = {"name": moves.name, "frame": "law", "law": {name: float(getattr(law, name)) for name in fields}}
    # Where the law pulls nowhere: the target frame (``law``), or the robot's search heading (``law-search``), which
    # the law's pull turns (``law-track``).
    no_pull = "search-heading" if moves.search else "target"
    return {**frame, "no_pull": no_pull, "heading": "law" if moves.track else "wander"}


def save_policy(policy: Policy, cfg: ScenarioConfig, path: str | os.PathLike[str]) -> Path:
    """Write atomically (temporary file, fsync, then rename) and return the path."""
    path = Path(path)
    header = json.dumps(header_for(policy, cfg), sort_keys=True).encode()
    arrays: dict[str, np.ndarray] = {
        "header": np.frombuffer(header, dtype=np.uint8),
        "prototypes": policy.discretization.prototypes.astype(np.float32),
        "labels": policy.discretization.labels.astype(np.float32),
        "offsets": policy.discretization.offsets.astype(np.int64),
        "tables": policy.tables.astype(np.float32),
        "robot_table": policy.robot_table.astype(np.int64),
    }
    if policy.visits is not None:
        arrays["visits"] = policy.visits.astype(np.uint64)
    if policy.discretization.scale is not None:
        arrays["scale"] = policy.discretization.scale.astype(np.float32)
    return save_npz_atomic(path, arrays)


def load_policy(path: str | os.PathLike[str]) -> tuple[Policy, dict[str, Any]]:
    """Read a policy file; raises :class:`PolicyFileError` with the reason when it cannot."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except OSError as exc:
        raise PolicyFileError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    except (ValueError, EOFError, zipfile.BadZipFile) as exc:
        # Not numpy's message: it would advise allow_pickle, which is never right for a policy file.
        raise PolicyFileError(f"{path}: not a policy file (not an .npz archive of plain arrays)") from exc
    missing = {"header", "prototypes", "labels", "offsets", "tables", "robot_table"} - set(arrays)
    if missing:
        raise PolicyFileError(
            f"{path}: not a policy file (no {', '.join(sorted(missing))}; a run folder holds its policy as "
            "policy.npz beside the checkpoint)"
        )
    try:
        header = json.loads(arrays["header"].tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PolicyFileError(f"{path}: unreadable header ({exc})") from exc
    if header.get("format") != FORMAT:
        raise PolicyFileError(f"{path}: not an {FORMAT} file")
    if header.get("format_version") != FORMAT_VERSION:
        raise PolicyFileError(
            f"{path}: format version {header.get('format_version')} is not supported"
            f" (this build reads {FORMAT_VERSION})"
        )
    try:
        disc = Discretization(arrays["prototypes"], arrays["labels"], arrays["offsets"], arrays.get("scale"))
        # Files written before rewards were named were all learned with their featurizer's paper reward, and before
        # action sets were named all used the compass.
        formulation = Formulation.of(
            header["featurizer"]["name"],
            header["reward"]["name"] if "reward" in header else "paper",
            header.get("action_set", {"name": "compass"})["name"],
        )
        policy = Policy(
            formulation=formulation,
            discretization=disc,
            tables=arrays["tables"],
            robot_table=arrays["robot_table"],
            action_steps=int(header["action_steps"]),
            action_mode=header["action_mode"],
            max_action_steps=int(header["max_action_steps"]),
            lost_behaviour=header["lost_behaviour"],
            visits=arrays.get("visits"),
            version=int(header["version"]),
            method=str(header["method"]),
            meta=dict(header.get("meta", {})),
            # Files written before the margin existed were read by the plain argmax.
            law_margin=float(header.get("law_margin", 0.0)),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise PolicyFileError(f"{path}: inconsistent policy file ({exc})") from exc
    problem = non_finite(arrays, policy.robot_table)
    if problem:
        raise PolicyFileError(f"{path}: {problem}; a policy acts on finite values only")
    return policy, header


FLOATS = ("tables", "prototypes", "labels", "scale")
"""A policy's arrays of real numbers, in a policy file and in a learner's checkpoint."""


def non_finite(arrays: dict[str, np.ndarray], robot_table: np.ndarray | None = None) -> str | None:
    """What holds a NaN or an infinite value among a policy's real arrays (:data:`FLOATS`), or None. A Q table names
    its robots where ``robot_table`` (robot -> table row) is known: an argmax over a NaN picks a move at random.

    >>> non_finite({"tables": np.array([[0.0, 1.0], [np.nan, 2.0]])}, robot_table=np.array([0, 1, 1]))
    'the Q table of robots 1-2 holds NaN (1 of 2 values)'
    """
    for name in FLOATS:
        values = arrays.get(name)
        if values is None or np.isfinite(values).all():
            continue
        bad = ~np.isfinite(values)
        what = "NaN" if np.isnan(values).any() else "infinity"
        if name != "tables":
            return f"its array {name} holds {what} ({int(bad.sum())} of {values.size} values)"
        row = int(np.flatnonzero(bad.any(axis=1))[0])
        robots = [] if robot_table is None else np.flatnonzero(robot_table == row).tolist()
        table = f"the Q table of {_robots(robots)}" if robots else f"Q table {row}"
        return f"{table} holds {what} ({int(bad[row].sum())} of {values.shape[1]} values)"
    return None


def _robots(robots: list[int]) -> str:
    """``robot 3``, ``robots 0-9`` or ``robots 1, 4``."""
    if len(robots) == 1:
        return f"robot {robots[0]}"
    if robots == list(range(robots[0], robots[-1] + 1)):
        return f"robots {robots[0]}-{robots[-1]}"
    return f"robots {', '.join(map(str, robots))}"


def scenario_from_header(header: dict[str, Any]) -> ScenarioConfig:
    """The scenario the policy was learned in, rebuilt from the header (unknown fields are errors)."""
    fields = dict(header["scenario"])
    # Files written before the hand-made controllers held their own force-law parameters carry them, and files
    # written while the learning-trial rules were scenario fields carry those (the formulation's now); no part of a
    # learned policy's test trials reads either.
    for moved in ("force", "lost_ends_trial", "timeout_terminal"):
        fields.pop(moved, None)
    return ScenarioConfig(**fields)
