"""docs/reference/protocol.md states the processes' defaults and the learner's status counters: each is checked against
the code that owns it, so the document cannot drift from ``--help`` again."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

from actors.config import ActorConfig
from learner.config import LearnerConfig
from learner.report import LearnerStatus

DOC = (Path(__file__).parents[2] / "docs" / "reference" / "protocol.md").read_text()


def defaults(config: type) -> dict[str, object]:
    return {f.name: f.default for f in dataclasses.fields(config) if f.default is not dataclasses.MISSING}


def test_every_flag_default_the_document_states_is_the_configuration_default() -> None:
    stated = re.findall(r"`--([a-z0-9-]+)` = ([0-9][0-9.]*)", DOC)
    configs = {"LearnerConfig": defaults(LearnerConfig), "ActorConfig": defaults(ActorConfig)}
    checked = set()
    for flag, value in stated:
        name = flag.replace("-", "_")
        owners = {owner: fields[name] for owner, fields in configs.items() if name in fields}
        assert owners, f"--{flag} is no field of {', '.join(configs)}"
        for owner, default in owners.items():
            said = f"docs/reference/protocol.md says --{flag} = {value}, {owner} says {default}"
            assert float(value) == default, said
        checked.add(flag)
    # What §5 states today; a rewording that stops matching the pattern would otherwise check nothing.
    assert {"checkpoint-interval", "broadcast-interval", "outbox-limit", "resend-after", "flush-timeout"} <= checked
    assert "status-interval" in checked


def test_the_learner_counters_table_is_the_learner_status() -> None:
    section = DOC[DOC.index("**Status counters.**") : DOC.index('The actor\'s (`role = "actor"`)')]
    documented = re.findall(r"^\| `([a-z_]+)` \|", section, flags=re.MULTILINE)
    assert documented == [f.name for f in dataclasses.fields(LearnerStatus)]
