"""The stop signals' handlers never hang the process they stop.

A handler runs on the main thread between two bytecodes, so it can land inside ``stop.wait()`` just as that has taken
back the event's lock; a handler that called ``stop.set()`` there waited for that lock forever (a learner hung so on
SIGTERM in the suite, its stack dump showed). Each test lands the handler exactly there: it calls it while holding
the lock CPython's ``threading.Event`` keeps in ``_cond``.
"""

from __future__ import annotations

import faulthandler
import signal
import threading
from collections.abc import Callable, Iterator

import pytest

from tools.system import Interrupts, stop_on_signals

STOPPING = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)


@pytest.fixture
def own_handlers() -> Iterator[None]:
    saved = {sig: signal.getsignal(sig) for sig in STOPPING}
    try:
        yield
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
        faulthandler.unregister(signal.SIGQUIT)


def handled_inside_wait(event: threading.Event, handle: Callable[[int, object], None], sig: int) -> bool:
    """Whether ``handle(sig)``, called while ``event``'s lock is held as inside its ``wait``, returns."""
    returned = threading.Event()

    def land() -> None:
        with event._cond:  # type: ignore[attr-defined]
            handle(sig, None)
        returned.set()

    threading.Thread(target=land, daemon=True).start()
    return returned.wait(10)


def test_a_stop_signal_inside_the_stop_events_wait_stops_the_process(own_handlers: None) -> None:
    stop = stop_on_signals()
    handler = signal.getsignal(signal.SIGTERM)
    assert callable(handler)
    assert handled_inside_wait(stop, handler, signal.SIGTERM), "the handler hung on the stop event's own lock"
    assert stop.wait(10) and not stop.urgent.is_set()
    # The second signal asks to hurry, from inside the same wait.
    assert handled_inside_wait(stop, handler, signal.SIGINT), "the second signal's handler hung"
    assert stop.urgent.wait(10)


def test_a_launchers_first_interrupt_inside_its_stop_events_wait_stops_the_run(own_handlers: None) -> None:
    said: list[str] = []
    interrupts = Interrupts(say=said.append)
    with interrupts.installed():
        assert handled_inside_wait(interrupts.stop, interrupts.handle, signal.SIGTERM)
    assert interrupts.stop.wait(10)
    assert interrupts.first == signal.SIGTERM and interrupts.exit_code == 143
    assert len(said) == 1 and said[0].startswith("SIGTERM: winding down cleanly")


def test_signals_that_land_inside_one_anothers_handler_still_stop_the_process(
    own_handlers: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Several SIGTERMs at once (a killed launcher's children get them together): the second lands inside the first's
    # handler, between any two of its bytecodes; here inside its look-up of the signal's name. An actor once counted
    # both as "again", set only the hurry and ran on with a full outbox.
    import tools.system

    real = signal.Signals
    nested = [signal.SIGTERM]

    def lands_inside(signum: int) -> signal.Signals:
        if nested:
            handler(nested.pop(), None)
        return real(signum)

    stop = stop_on_signals()
    handler = signal.getsignal(signal.SIGTERM)
    assert callable(handler)
    monkeypatch.setattr(tools.system.signal, "Signals", lands_inside)
    handler(signal.SIGTERM, None)
    assert not nested and stop.wait(10) and stop.urgent.wait(10)
    interrupts = Interrupts(say=lambda line: None)
    nested.append(signal.SIGTERM)
    with interrupts.installed():
        handler = interrupts.handle
        interrupts.handle(signal.SIGTERM, None)
    assert not nested and interrupts.stop.wait(10) and interrupts.first == signal.SIGTERM
