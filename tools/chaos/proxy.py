"""The links of a chaos run with network faults: a TCP proxy per client that relays its connections to the router,
each direction through a FIFO that can hold chunks back (this kernel has no ``netem`` qdisc, so delay and loss are
emulated above TCP).

* **delay**: every chunk is delivered ``delay_s`` after it was read, in order.
* **loss**: each chunk the proxy relays (up to :data:`CHUNK_BYTES`) is held back one retransmission timeout
  (``rto_s``) with probability ``loss``, with everything behind it: what a lost segment does to a TCP stream (its
  bytes are never lost, the stream stalls until the sender re-sends them).

Usage (the listening sockets are made in the caller's network namespace, the thread's at :meth:`Proxies.start`)::

    proxies = Proxies(("127.0.0.1", router_port)).start()
    port = proxies.add("actor-0", "10.213.8.1")      # actor-0 connects there instead of to the router
    proxies.shape(Shaping(delay_s=0.025))            # every link, until shaped again
    proxies.relayed()                                # bytes relayed per link and direction
    proxies.close()
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import threading
from dataclasses import dataclass

log = logging.getLogger("tools.chaos")  # one name for the package: its lines read "tools.chaos: ..."

CHUNK_BYTES = 64 * 1024
QUEUE_CHUNKS = 256
"""Chunks a direction holds at most (16 MiB): past it the proxy stops reading, so back-pressure reaches the sender."""
DEFAULT_RTO_S = 0.2
"""Linux's minimum TCP retransmission timeout."""
FLUSH_S = 1.0
"""After one end closed, how long what it sent last may take to reach the other (beyond the shaping's own delay)."""


@dataclass(frozen=True, slots=True)
class Shaping:
    delay_s: float = 0.0
    """Added to every chunk, each direction."""
    loss: float = 0.0
    """Probability that a chunk is held back ``rto_s`` more."""
    rto_s: float = DEFAULT_RTO_S


class Proxies:
    """One asyncio loop on a thread of its own, relaying every link's connections to ``upstream``."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self.shaping = Shaping()
        self._relayed: dict[str, list[int]] = {}
        self._loop = asyncio.new_event_loop()
        self._servers: list[asyncio.Server] = []
        self._thread = threading.Thread(target=self._loop.run_forever, name="chaos-links", daemon=True)
        self._random = random.Random(0x11CC)

    def start(self) -> Proxies:
        self._thread.start()
        return self

    def add(self, name: str, host: str) -> int:
        """A link named ``name`` listening on ``host`` (a free port): the port."""
        self._relayed[name] = [0, 0]
        future = asyncio.run_coroutine_threadsafe(self._listen(name, host), self._loop)
        return future.result(timeout=10)

    def shape(self, shaping: Shaping) -> None:
        """Every link from now on (a chunk already read keeps its delivery time)."""
        self.shaping = shaping  # one reference, read by the loop's thread: no lock needed

    def relayed(self) -> dict[str, dict[str, int]]:
        """Bytes relayed so far per link (handed to the far end's socket): ``up`` from the client to the router,
        ``down`` back."""
        return {name: {"up": up, "down": down} for name, (up, down) in self._relayed.items()}

    def close(self) -> None:
        async def stop() -> None:
            for server in self._servers:
                server.close()
            current = asyncio.current_task()
            tasks = [t for t in asyncio.all_tasks() if t is not current]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        if self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(stop(), self._loop).result(timeout=10)
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
        self._loop.close()

    async def _listen(self, name: str, host: str) -> int:
        server = await asyncio.start_server(lambda r, w: self._connection(name, r, w), host, 0)
        self._servers.append(server)
        port: int = server.sockets[0].getsockname()[1]
        return port

    async def _connection(self, name: str, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        try:
            router_r, router_w = await asyncio.open_connection(*self.upstream)
        except OSError as exc:  # the router is down (a restart): the client retries, as with no proxy
            log.debug("link %s: router unreachable: %s", name, exc)
            client_w.transport.abort()
            return
        counts = self._relayed[name]
        pipes = [
            asyncio.create_task(self._pipe(client_r, router_w, counts, 0)),
            asyncio.create_task(self._pipe(router_r, client_w, counts, 1)),
        ]
        try:
            await asyncio.wait(pipes, return_when=asyncio.FIRST_COMPLETED)
        finally:
            # Either side gone (closed, reset, or its lease expired behind a partition): drop both at once, as a
            # broken link does, instead of waiting on a peer that may never read again.
            for writer in (client_w, router_w):
                writer.transport.abort()
            for pipe in pipes:
                pipe.cancel()
            await asyncio.gather(*pipes, return_exceptions=True)

    async def _pipe(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, counts: list[int], i: int
    ) -> None:
        """Relay one direction: read, stamp each chunk with its delivery time, deliver in order. Ends at the reader's
        end (after a bounded flush) or as soon as the writer fails."""
        queue: asyncio.Queue[tuple[float, bytes] | None] = asyncio.Queue(QUEUE_CHUNKS)
        loop = asyncio.get_running_loop()

        async def deliver() -> None:
            while (item := await queue.get()) is not None:
                due, chunk = item
                wait = due - loop.time()
                if wait > 0:
                    await asyncio.sleep(wait)
                # Counted before the write: the far end may read the chunk (and a caller ask for the counts) before
                # this task runs again.
                counts[i] += len(chunk)
                writer.write(chunk)
                await writer.drain()

        sender = asyncio.create_task(deliver())

        async def offer(item: tuple[float, bytes] | None) -> bool:
            """Queue ``item`` unless the sender fails first (it would never take it): whether it is queued."""
            put = asyncio.create_task(queue.put(item))
            await asyncio.wait([put, sender], return_when=asyncio.FIRST_COMPLETED)
            if not put.done():
                put.cancel()
            return put.done() and not put.cancelled()

        try:
            while chunk := await reader.read(CHUNK_BYTES):
                shaping = self.shaping
                held = shaping.delay_s
                if shaping.loss and self._random.random() < shaping.loss:
                    held += shaping.rto_s
                if not await offer((loop.time() + held, chunk)):
                    return
            if await offer(None):
                shaping = self.shaping
                await asyncio.wait_for(sender, FLUSH_S + shaping.delay_s + shaping.rto_s)
        except (ConnectionError, OSError, TimeoutError):
            pass  # a reset or broken link ends the connection like an end of stream
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, ConnectionError, OSError):
                await sender
