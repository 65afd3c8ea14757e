"""Which actors the learner knows, from their liveliness tokens: those alive now and every one seen in the run.

Usage (``on_join``/``on_leave`` run on the transport's liveliness thread; every method takes the object's own lock)::

    members = Membership()
    transport.liveliness_subscribe(keys.alive("actor"), members.on_join, members.on_leave)
    members.live(), members.seen()          # sorted actor ids
    meta = members.to_meta()                # for a checkpoint: the actors seen survive a resume
    members.restore(meta)

A token's key names its actor in its last chunk. A chunk that is not a protocol identifier (docs/reference/protocol.md
§1) is no actor: the token is refused, logged and counted once (``refused``) while it is present, and never listed."""

from __future__ import annotations

import logging
import threading
from typing import Any

from protocol import ProtocolError, check_id

log = logging.getLogger(__name__)

_LOG_FIRST = 10
_LOG_EVERY = 1000


class Membership:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._live: set[str] = set()
        self._seen: set[str] = set()
        self._refused_now: set[str] = set()
        """Refused tokens present now: history and live delivery may both report one, and it counts once."""
        self.refused = 0
        """Tokens refused over the run because their id is not an identifier."""

    def on_join(self, key: str) -> None:
        actor = key.rsplit("/", 1)[-1]
        try:
            check_id(actor, "actor id")
        except ProtocolError as exc:
            self._refuse(key, actor, exc)
            return
        with self._lock:
            self._live.add(actor)
            self._seen.add(actor)
            live = len(self._live)
        log.info("actor %s joined (%d live)", actor, live)

    def on_leave(self, key: str) -> None:
        actor = key.rsplit("/", 1)[-1]
        with self._lock:
            if actor in self._refused_now:
                self._refused_now.discard(actor)
                return
            if actor not in self._live:
                return
            self._live.discard(actor)
            live = len(self._live)
        log.info("actor %s left (%d live)", actor, live)

    def _refuse(self, key: str, actor: str, error: ProtocolError) -> None:
        with self._lock:
            if actor in self._refused_now:
                return
            self._refused_now.add(actor)
            self.refused += 1
            n = self.refused
        if n <= _LOG_FIRST or n % _LOG_EVERY == 0:  # a hostile peer may declare tokens at line rate
            log.warning("refused the liveliness token %r (#%d): %s", key, n, error)

    def live(self) -> list[str]:
        with self._lock:
            return sorted(self._live)

    def seen(self) -> list[str]:
        with self._lock:
            return sorted(self._seen)

    def to_meta(self) -> dict[str, Any]:
        with self._lock:
            return {"seen_actors": sorted(self._seen), "refused_tokens": self.refused}

    def restore(self, meta: dict[str, Any]) -> None:
        """The actors seen and the refusals counted before a resume; who is alive now, liveliness reports anew."""
        with self._lock:
            self._seen = {str(actor) for actor in meta["seen_actors"]}
            self.refused = int(meta["refused_tokens"])
