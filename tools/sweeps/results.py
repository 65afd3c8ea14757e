"""How ``reproduce`` and ``ablate`` leave their results: one folder with the report as JSON and as a Markdown table,
a chart, and every learned policy file::

    write_results(out_dir, report, markdown_table(report), bar_chart(report), "figure5.png", policies)
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from algorithm.files import write_atomic
from algorithm.policy import Policy
from algorithm.policy_file import save_policy
from sim import ScenarioConfig

if TYPE_CHECKING:
    from matplotlib.figure import Figure

CHART_DPI = 110
RESULTS = "results.json"


def write_results(
    out_dir: Path,
    report: dict[str, Any],
    markdown: str,
    chart: Figure,
    chart_name: str,
    policies: Mapping[str, tuple[Policy | None, ScenarioConfig]],
) -> None:
    """``results.json``, ``results.md``, the chart as ``chart_name`` and each policy as ``policies/<name>.npz`` (a
    learning process with no policy file, the neural reference, has none)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, (policy, cfg) in policies.items():
        if policy is not None:
            save_policy(policy, cfg, out_dir / "policies" / f"{name}.npz")
    write_atomic(out_dir / RESULTS, json.dumps(report, indent=2).encode())
    (out_dir / "results.md").write_text(markdown)
    chart.savefig(out_dir / chart_name, dpi=CHART_DPI)
