"""A fork server for a console script: one Python process imports the script's entry point and the modules its
commands load once, then forks a fresh copy of itself for every command line, which runs the entry point as the
script would, in its own session, folder and environment. A command costs a fork (~10 ms) instead of a new
interpreter and its imports (0.7-3 s for ``ennc-ql``).

Run as ``python _forkserver.py SCRIPT MODULE:FUNCTION [PRELOAD...]``; :class:`ForkServer` starts it and sends it
requests. One JSON line per request on stdin (``argv``, ``cwd``, ``env``, ``timeout``), one JSON line per answer on
stdout (``returncode``, ``stdout`` and ``stderr`` in base64, ``timed_out``), or ``{"refused": why}``.

The child is the script's process in all that a command can see: ``sys.argv``, ``sys.path[0]``, the working folder,
the whole environment (read by the command when it runs: ``shutil.which`` reads PATH at each call), stdin from
/dev/null (as pytest gives it), stdout and stderr on pipes, and the interpreter's own ending (``sys.exit`` from the
top level: its status, threads joined, atexit handlers run, streams flushed). It differs where a command should not
look: its modules are not torn down at the end (the command's own garbage is collected, for what its finalizers
print), the server's objects are frozen out of the garbage collector's sight, and the hash seed is the server's.
What a new interpreter reads when it starts (``PYTHON*``, the locale) is the server's too: :meth:`ForkServer.run`
refuses to change it."""

from __future__ import annotations

import atexit
import base64
import contextlib
import gc
import importlib
import json
import locale
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

READY = b'{"ready": true}\n'
STARTUP_ENV = ("PYTHON", "LC_", "LANG")
"""What an interpreter reads once, when it starts: a fork can't change these."""
DRAIN_S = 5.0
"""After a kill, how long the server still reads what the killed group wrote (a process that escaped the group
would otherwise keep the pipes open for good)."""


class ForkServer:
    """The server process, started at once; :meth:`run` a command line, :meth:`close` at the end."""

    def __init__(self, script: Path, entry_point: str, preload: Sequence[str]) -> None:
        # stdout and stderr pipes, as the commands' own: Python sets its streams up by what they are when it starts
        # (a TextIOWrapper on a file would seek on a pipe).
        self.proc = subprocess.Popen(
            [sys.executable, __file__, str(script), entry_point, *preload],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,  # its group holds the server alone; each command has a session of its own
            env={**os.environ, "COLUMNS": "120"},
        )
        assert self.proc.stderr is not None
        os.set_blocking(self.proc.stderr.fileno(), False)
        self.said = b""
        if self._answer(timeout=120.0) != json.loads(READY):
            self.close()
            raise RuntimeError(f"the fork server did not start:\n{self.stderr()}")
        if self.stderr():  # a warning at import: the real script prints it before every command's own output
            self.close()
            raise RuntimeError(f"importing the preloaded modules printed:\n{self.stderr()}")

    def run(
        self, argv: Sequence[str], cwd: Path, env: dict[str, str], timeout: float
    ) -> tuple[int, bytes, bytes, bool]:
        """``SCRIPT argv`` in ``cwd`` with exactly ``env``: its exit status (``-N`` for signal N, as subprocess says
        it), stdout, stderr, and whether it ran past ``timeout`` (then its session was killed)."""
        fixed = {
            key for key in {*env, *os.environ} if key.startswith(STARTUP_ENV) and env.get(key) != os.environ.get(key)
        }
        if fixed:
            raise ValueError(f"{sorted(fixed)}: read at the interpreter's start; run the real script for these")
        assert self.proc.stdin is not None
        request = {"argv": list(argv), "cwd": str(cwd), "env": env, "timeout": timeout}
        self.proc.stdin.write(json.dumps(request).encode() + b"\n")
        self.proc.stdin.flush()
        answer = self._answer(timeout=timeout + DRAIN_S + 30.0)
        if answer is None:
            raise RuntimeError(f"the fork server did not answer {list(argv)}:\n{self.stderr()}")
        if "refused" in answer:
            raise RuntimeError(f"the fork server refused {list(argv)}: {answer['refused']}")
        out, err = (base64.b64decode(answer[name]) for name in ("stdout", "stderr"))
        return answer["returncode"], out, err, answer["timed_out"]

    def stderr(self) -> str:
        """All the server wrote on its stderr so far: nothing, unless an import printed or the server failed."""
        assert self.proc.stderr is not None
        with contextlib.suppress(BlockingIOError):
            while not self.proc.stderr.closed and (chunk := os.read(self.proc.stderr.fileno(), 1 << 16)):
                self.said += chunk
        return self.said.decode(errors="replace")

    def close(self) -> None:
        """End of input ends the server; its group is killed after it in any case, so nothing of it is left."""
        assert self.proc.stdin is not None and self.proc.stdout is not None and self.proc.stderr is not None
        self.proc.stdin.close()
        with contextlib.suppress(subprocess.TimeoutExpired):  # then killed: its status says so
            self.proc.wait(timeout=30.0)
        with contextlib.suppress(ProcessLookupError):  # the usual case: the group ended with the server
            os.killpg(self.proc.pid, signal.SIGKILL)
        self.proc.wait()
        self.stderr()
        self.proc.stdout.close()
        self.proc.stderr.close()

    def _answer(self, timeout: float) -> Any:
        """The server's next JSON line, or None where it ends or says nothing for ``timeout`` seconds."""
        assert self.proc.stdout is not None
        if not select.select([self.proc.stdout], [], [], timeout)[0]:
            return None
        line = self.proc.stdout.readline()
        return json.loads(line) if line else None


def text(data: bytes) -> str:
    """Bytes as ``subprocess`` in text mode gives them: the locale's encoding, universal newlines."""
    return data.decode(locale.getpreferredencoding(False)).replace("\r\n", "\n").replace("\r", "\n")


def serve(requests: IO[bytes], replies: IO[bytes]) -> dict[str, Any] | None:
    """Answer requests until stdin ends (None); in a forked child, its request (the caller runs the command)."""
    for line in requests:
        request = json.loads(line)
        # A thread other than this one (Python's or native, /proc counts both) would be left behind by the fork with
        # whatever lock it held, held for good in the child.
        threads = os.listdir("/proc/self/task")
        if len(threads) != 1:
            replies.write(json.dumps({"refused": f"{len(threads)} threads in the server"}).encode() + b"\n")
            replies.flush()
            continue
        out_r, out_w = os.pipe()
        err_r, err_w = os.pipe()
        sys.stdout.flush()  # what the server's streams hold, each child would write again
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            os.close(out_r)
            os.close(err_r)
            os.dup2(out_w, 1)
            os.dup2(err_w, 2)
            os.close(out_w)
            os.close(err_w)
            requests.close()
            replies.close()
            return request
        os.close(out_w)
        os.close(err_w)
        replies.write(json.dumps(wait(pid, out_r, err_r, request["timeout"])).encode() + b"\n")
        replies.flush()
    return None


def wait(pid: int, out: int, err: int, timeout: float) -> dict[str, Any]:
    """Read the child's stdout and stderr to their ends and wait for it, as ``Popen.communicate`` does; past
    ``timeout`` kill its session (its own group, from ``setsid``)."""
    chunks: dict[int, list[bytes]] = {out: [], err: []}
    pidfd = os.pidfd_open(pid)
    watched = {out, err, pidfd}
    deadline = time.monotonic() + timeout
    timed_out = False
    while watched:
        left = deadline - time.monotonic()
        if left <= 0 and not timed_out:
            timed_out = True
            with contextlib.suppress(ProcessLookupError):  # the group is gone; a process outside it holds a pipe
                os.killpg(pid, signal.SIGKILL)
            deadline = time.monotonic() + DRAIN_S
            continue
        if left <= 0:
            break
        for fd in select.select(list(watched), [], [], left)[0]:
            data = b"" if fd == pidfd else os.read(fd, 1 << 16)
            if data:
                chunks[fd].append(data)
            else:
                watched.discard(fd)
    for fd in (out, err, pidfd):
        os.close(fd)
    _, status = os.waitpid(pid, 0)
    return {
        "returncode": os.waitstatus_to_exitcode(status),
        "stdout": base64.b64encode(b"".join(chunks[out])).decode(),
        "stderr": base64.b64encode(b"".join(chunks[err])).decode(),
        "timed_out": timed_out,
    }


STATUS: int | None = None
"""In a forked child, its exit status once the command has ended (None in the server)."""


def end() -> None:
    """The last atexit handler (registered before any module's own): a child ends as the interpreter would after its
    atexit handlers, with its streams flushed and the status that Python would give, but without tearing down its
    modules (0.2 s, 0.7 s with torch loaded). The command's garbage is collected first, for what its finalizers say."""
    if STATUS is None:
        return
    gc.collect()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(STATUS)


def start(script: str, preload: Sequence[str]) -> tuple[IO[bytes], IO[bytes]]:
    """The server's setup: its request and reply pipes set apart, the modules imported, a single thread."""
    requests = os.fdopen(os.dup(0), "rb")
    replies = os.fdopen(os.dup(1), "wb")
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)  # the children's stdin, as the tests' own
    os.close(null)
    os.dup2(2, 1)  # whatever an import prints goes to stderr, where the client looks for it
    sys.path[0] = os.path.dirname(os.path.realpath(script))  # where Python puts a script's folder
    atexit.register(end)
    for name in preload:
        importlib.import_module(name)
    # Out of the garbage collector's sight: a child's collections walk only what the command made (the server's
    # objects took 0.13 s more a command).
    gc.freeze()
    # numpy's OpenBLAS starts a pool of threads at import and stops it at every fork (its own atfork handler): one
    # fork leaves the server with its one thread, which ``serve`` insists on.
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)
    sys.stdout.flush()
    sys.stderr.flush()
    replies.write(READY)
    replies.flush()
    return requests, replies


if __name__ == "__main__":
    script, entry_point, *preload = sys.argv[1:]
    request = serve(*start(script, preload))
    if request is not None:
        # The forked child: the console script's process from here on.
        os.setsid()
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        sys.argv = [script, *request["argv"]]
        module, function = entry_point.split(":")
        try:
            sys.exit(getattr(importlib.import_module(module), function)())
        except SystemExit as stop:  # Python prints a code that is not a number, and exits with 1
            STATUS = 0 if stop.code is None else stop.code if isinstance(stop.code, int) else 1
            raise
        except Exception:  # Python prints the traceback, and exits with 1
            STATUS = 1
            raise
