"""Membership from liveliness tokens: valid ids join and leave; a token under an id that is not an identifier is
refused, counted and logged once, and never listed (not even in report.json)."""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

import pytest

from learner.config import LearnerConfig
from learner.membership import Membership
from learner.service import LearnerService
from learner.wiring import connect as connect_learner
from protocol import InMemoryBus, InMemoryTransport

PREFIX = "enncql/v1/alive/actor"


def test_actors_join_and_leave() -> None:
    members = Membership()
    members.on_join(f"{PREFIX}/actor-1")
    members.on_join(f"{PREFIX}/actor-0")
    members.on_join(f"{PREFIX}/actor-0")  # history and live delivery may both report a token
    members.on_leave(f"{PREFIX}/actor-1")
    assert members.live() == ["actor-0"] and members.seen() == ["actor-0", "actor-1"]
    resumed = Membership()
    resumed.restore(members.to_meta())
    assert resumed.live() == [] and resumed.seen() == ["actor-0", "actor-1"]


def test_a_token_under_an_invalid_id_is_refused_once_while_present(caplog: pytest.LogCaptureFixture) -> None:
    members = Membership()
    with caplog.at_level(logging.WARNING, logger="learner.membership"):
        members.on_join(f"{PREFIX}/-not-an-id")
        members.on_join(f"{PREFIX}/-not-an-id")  # reported twice: still one refusal
        members.on_leave(f"{PREFIX}/-not-an-id")
        members.on_join(f"{PREFIX}/{'x' * 65}")  # too long for an identifier
    assert members.refused == 2 and members.live() == [] and members.seen() == []
    logged = [r.getMessage() for r in caplog.records]
    assert len(logged) == 2 and "-not-an-id" in logged[0] and "x" * 65 in logged[1]  # each refusal logged once
    members.on_join(f"{PREFIX}/-not-an-id")  # declared again after it left: a new refusal
    assert members.refused == 3
    resumed = Membership()
    resumed.restore(members.to_meta())
    assert resumed.refused == 3


def test_the_report_lists_only_valid_actors_and_counts_the_refused_token(tmp_path: Path) -> None:
    bus = InMemoryBus()
    with InMemoryTransport(bus) as lt, InMemoryTransport(bus) as peer:
        peer.liveliness_token(peer.keys.alive("actor", "actor-0"))
        peer.liveliness_token(f"{peer.keys.root}/alive/actor/-not-an-id")  # before the learner: reported as history
        service = LearnerService(lt, LearnerConfig(), tmp_path)
        handles = connect_learner(service, lt)
        stopped = threading.Event()
        stopped.set()
        report = service.run(stopped)
        handles.close()  # the ExitStack connect returned: every handle, in reverse order
    written = json.loads((tmp_path / "report.json").read_text())
    assert report.actors == written["actors"] == ["actor-0"] and written["live_actors"] == ["actor-0"]
    assert report.refused_tokens == written["refused_tokens"] == 1
