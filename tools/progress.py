"""Progress of the long commands (``up``, ``reproduce``, ``bench``) on stderr.

On a terminal it is a tqdm bar whose postfix carries the command's live figures, with milestones printed above it
and log records routed around it; anywhere else (CI logs, files, tests) a redrawn bar is noise, so it prints plain
lines instead: a milestone at once, the live figures at most every ``every`` seconds. Usage::

    with ProgressBar("reproduce", total=12, unit="jobs") as bar:
        bar.show(status="vqql-local-16[0]: phase 2: 30/60 trial batches")  # live figures, rate-limited off a tty
        bar.mark("vqql-local-16[0]: 51.94%", n=1)  # a milestone: always printed, kept above the bar
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import ExitStack
from types import TracebackType
from typing import TextIO

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

PLAIN_EVERY = 5.0
"""Seconds between plain lines of live figures when stderr is not a terminal."""
BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n:.0f}/{total:.0f} {unit} [{elapsed}<{remaining}]{postfix}"
"""tqdm's default shows a float position with every decimal; positions here are whole seconds, jobs or phases."""


def plain_line(desc: str, n: float, total: float, unit: str, status: str) -> str:
    """One line of progress for a log: ``up [35/480 s] exploring: ...``."""
    return f"{desc} [{n:.0f}/{total:.0f} {unit}] {status}".rstrip()


def _drawable(stream: TextIO) -> bool:
    """A terminal with a width: tqdm fits the bar to the width and draws nothing on a 0-column pseudo-terminal."""
    try:
        return stream.isatty() and os.get_terminal_size(stream.fileno()).columns > 0
    except (OSError, ValueError):
        return False


class ProgressBar:
    """A bar over ``total`` units on a terminal, plain lines elsewhere; a context manager.

    ``tty`` overrides the terminal test of ``stream`` (default: stderr), so tests can render either mode.
    """

    def __init__(
        self,
        desc: str,
        total: float,
        unit: str,
        *,
        every: float = PLAIN_EVERY,
        stream: TextIO | None = None,
        tty: bool | None = None,
    ) -> None:
        self.desc, self.total, self.unit, self.every = desc, total, unit, every
        self.stream = stream if stream is not None else sys.stderr
        self.tty = _drawable(self.stream) if tty is None else tty
        self.n = 0.0
        self.status = ""
        self._last_line = -float("inf")
        self._last_text: str | None = None
        self._stack = ExitStack()
        self._bar: tqdm | None = None
        if self.tty:
            # Log records written straight to stderr would tear the bar; tqdm prints them above it instead.
            self._stack.enter_context(logging_redirect_tqdm())
            self._bar = self._stack.enter_context(
                tqdm(total=total, desc=desc, unit=unit, file=self.stream, bar_format=BAR_FORMAT, dynamic_ncols=True)
            )

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        self._stack.close()

    def show(self, n: float | None = None, status: str | None = None) -> None:
        """Move to ``n`` and/or replace the live figures; off a terminal a line at most every ``every`` seconds."""
        self._set(n, status)
        if self._bar is not None:
            self._bar.refresh()
        elif time.monotonic() - self._last_line >= self.every and self.status != self._last_text:
            # A log reader gains nothing from the same line again (a wind-down's phase holds its text for seconds).
            self._line(self.status)

    def mark(self, message: str, n: float | None = None) -> None:
        """A milestone (a job finished, a phase measured): printed now and kept, on a terminal above the bar."""
        self._set(n, None)
        if self._bar is not None:
            self._bar.write(f"{self.desc}: {message}", file=self.stream)
            self._bar.refresh()
        else:
            self._line(message)

    def _set(self, n: float | None, status: str | None) -> None:
        if n is not None:
            self.n = n
        if status is not None:
            self.status = status
        if self._bar is not None:
            self._bar.n = self.n
            self._bar.set_postfix_str(self.status, refresh=False)

    def _line(self, text: str) -> None:
        print(plain_line(self.desc, self.n, self.total, self.unit, text), file=self.stream, flush=True)
        self._last_line, self._last_text = time.monotonic(), text
