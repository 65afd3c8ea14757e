"""Colours and line widths of the views, fixed per series so that the same thing looks the same in every panel.

The palette is Okabe & Ito's, chosen to stay distinguishable under the common colour-vision deficiencies; on the
viewer's dark background the light grey stands in for their black. Pure data: nothing here imports Rerun.
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Mapping

Rgb = tuple[int, int, int]

ORANGE: Rgb = (230, 159, 0)
SKY_BLUE: Rgb = (86, 180, 233)
BLUISH_GREEN: Rgb = (0, 158, 115)
YELLOW: Rgb = (240, 228, 66)
BLUE: Rgb = (0, 114, 178)
VERMILLION: Rgb = (213, 94, 0)
REDDISH_PURPLE: Rgb = (204, 121, 167)
LIGHT_GREY: Rgb = (225, 225, 225)
MID_GREY: Rgb = (150, 150, 150)
BLACK: Rgb = (0, 0, 0)
DARK_VERMILLION: Rgb = (140, 55, 0)
"""Not Okabe & Ito's: a ninth reference needed a colour, and this one reads as kin of ``force-6d-shared``'s
vermillion, the law it extends."""

ACTOR_PALETTE: tuple[Rgb, ...] = (ORANGE, SKY_BLUE, BLUISH_GREEN, REDDISH_PURPLE, VERMILLION, BLUE, YELLOW)
"""One colour per actor; the learner's own series are :data:`LEARNER` so that they never take an actor's colour."""

LEARNER: Rgb = LIGHT_GREY
"""The learner's series where they share a panel with the actors' (throughput, policy version, RSS)."""

LEARNED: Rgb = YELLOW
"""The learned policy on the test trials: the learning curve, and its final figure."""

REFERENCES: dict[str, tuple[str, Rgb]] = {
    "random": ("random", MID_GREY),
    "local": ("local", SKY_BLUE),
    "a-cmommt": ("A-CMOMMT", REDDISH_PURPLE),
    "a-cmommt-public": ("A-CMOMMT, public untuned parameters", ORANGE),
    "a-cmommt-oracle": ("A-CMOMMT oracle (true positions)", BLUE),
    "force-6d": ("force law on the 6-D state", BLUISH_GREEN),
    "force-6d-shared": ("force law, 6-D state + shared flags", VERMILLION),
    "force-recall": ("force law + shared flags + memory", DARK_VERMILLION),
}
"""Legend name and colour of each hand-made controller (by its ``sim.CONTROLLERS`` name) drawn as a reference level
on the learning curve."""


def cooperation_table(rows: Mapping[str, Mapping[str, float]], trials: int) -> str:
    """Markdown: each team's spread over the targets per robot-step, the learned policy first, then the references
    in :data:`REFERENCES`' order."""
    names = [n for n in ("learned", *REFERENCES) if n in rows]
    lines = [
        f"Per robot-step on {trials} test trials: a robot that sees only teammate-watched targets adds nothing where "
        "it stands; one that sees none is searching.",
        "",
        "| policy | % observed | only watched in view % | none in view % | robots per covered target |",
        "|---|---|---|---|---|",
    ]
    for name in names:
        row = rows[name]
        label = "learned policy" if name == "learned" else REFERENCES[name][0]
        coverage = f"{row['coverage']:.2f}" if "coverage" in row else "–"
        if "learned_minus" in row:
            coverage += f" (learned {row['learned_minus']:+.2f})"
        lines.append(
            f"| {label} | {coverage} | {row['only_shared_pct']:.1f} | {row['none_in_view_pct']:.1f} "
            f"| {row['robots_per_covered_target']:.3f} |"
        )
    return "\n".join(lines)


MOVE_PALETTE: tuple[Rgb, ...] = (BLUE, YELLOW, VERMILLION, SKY_BLUE, BLACK, BLUISH_GREEN, ORANGE, REDDISH_PURPLE)
"""One colour per action index, all eight of Okabe and Ito's, in the policy figure's move map: neighbouring moves
(``toward`` and ``toward-left``, N and NE, …), whose regions usually meet, differ in lightness, and the two closest
colours (vermillion, orange) go to opposite moves."""

Q_STATS: dict[str, Rgb] = {"mean": LIGHT_GREY, "min": SKY_BLUE, "max": ORANGE}

# Arena drawing: robots and their sensing disks in one hue, targets in a pair that differs in hue and lightness.
ROBOT: Rgb = SKY_BLUE
OBSERVED: Rgb = BLUISH_GREEN
UNOBSERVED: Rgb = VERMILLION
BOUNDARY: Rgb = MID_GREY
SENSING_ALPHA = 70
"""Opacity (of 255) of a sensing disk: overlapping disks stay readable, a lone disk stays visible."""

MAIN_WIDTH = 3.0
"""UI points: the series a panel is about (the learning curve)."""
WIDTH = 2.0
REFERENCE_WIDTH = 1.5
MARKER_SIZE = 12.0
"""UI points: a series drawn as markers (the final figure, beside the curve)."""


def actor_color(actor_id: str) -> Rgb:
    """The colour of ``actor_id`` in every view: the trailing number k of ``actor-<k>`` (as ``ennc-ql up`` names
    its actors) picks palette entry k, so the actors of a run differ and keep their colour when others join; an id
    without a number is hashed (stable across processes, though two such ids may collide)."""
    match = re.search(r"(\d+)$", actor_id)
    index = int(match.group(1)) if match else zlib.crc32(actor_id.encode())
    return ACTOR_PALETTE[index % len(ACTOR_PALETTE)]


def rgba(color: Rgb, alpha: int = 255) -> tuple[int, int, int, int]:
    return (*color, alpha)
