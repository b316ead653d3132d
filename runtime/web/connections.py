"""The web view's listening socket and its connections, bounded (docs/web.md, "Bounds").

The server accepts its connections itself (``Listener``) so that it decides before a
connection costs more than its descriptor, TLS or not:

- **per address**: at most PER_ADDRESS connections from one address, **in all**: at most
  MAX_CONNECTIONS, and never more than the process's open-file limit allows (less
  NOFILE_RESERVE for the feed, the console sessions, the files it reads): the server
  never runs out of descriptors (EMFILE), which would stop it accepting anybody;
- when a bound is reached, the connection of that address (or of any, for the total)
  that has been idle longest is dropped to make room: a connection is idle while no
  request of it is being handled, so an open page (its WebSocket) is never dropped, and
  half-sent requests are; when none is idle, the new connection is closed;
- **time**: a request's headers must arrive within HEADER_TIMEOUT_S of the connection's
  start or of its previous response (aiohttp's keep-alive timer, which runs from the
  connection's start: ``keepalive_timeout``), a TLS handshake within as long, a request
  body within as long (``WebView``).

One line in the log every LOG_EVERY_S at most says how many were refused or dropped.
"""

from __future__ import annotations

import asyncio
import errno
import logging
import resource
import socket
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass

log = logging.getLogger(__name__)

#: a request's headers (and a TLS handshake, and a request's body) must arrive within, s
HEADER_TIMEOUT_S = 10.0
#: connections at once, in all
MAX_CONNECTIONS = 512
#: connections at once from one address (a browser opens 6 to a server, plus one per page)
PER_ADDRESS = 64
#: descriptors kept for the rest of the process (the feed, console sessions, files)
NOFILE_RESERVE = 64
#: the refusals are logged at most this often, s
LOG_EVERY_S = 10.0
#: after the system refused an accept (out of descriptors or memory), accepting waits, s
ACCEPT_RETRY_S = 1.0


def total_bound(limit: int = MAX_CONNECTIONS) -> int:
    """MAX_CONNECTIONS, or fewer when the open-file limit (RLIMIT_NOFILE) would not hold
    them beside NOFILE_RESERVE."""
    soft, _hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return limit
    return max(1, min(limit, soft - NOFILE_RESERVE))


@dataclass(eq=False)
class Conn:
    """One accepted connection."""

    address: str
    #: loop seconds it became idle (accepted, or its last request handled)
    since: float
    #: requests of it being handled now (a page's WebSocket is one for its whole life)
    busy: int = 0
    transport: asyncio.BaseTransport | None = None
    #: its set-up (the TLS handshake), until the transport is made
    task: asyncio.Task[None] | None = None

    def closed(self) -> bool:
        if self.transport is not None:
            return self.transport.is_closing()
        return self.task is not None and self.task.done()

    def drop(self) -> None:
        if self.transport is not None:
            abort = getattr(self.transport, "abort", None)
            if abort is not None:
                abort()
            else:
                self.transport.close()
        elif self.task is not None:
            self.task.cancel()


class Listener:
    """A listening TCP socket whose connections go to ``factory`` (aiohttp's server),
    within the bounds of the module docstring."""

    def __init__(self, factory: Callable[[], asyncio.BaseProtocol],
                 ssl_context: ssl.SSLContext | None, total: int | None = None,
                 per_address: int = PER_ADDRESS,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.factory = factory
        self.ssl_context = ssl_context
        self.total = total_bound() if total is None else total
        self.per_address = per_address
        self.clock = clock
        self.conns: set[Conn] = set()
        self._by_transport: dict[asyncio.BaseTransport, Conn] = {}
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        #: counters (tests, the log line): connections refused, and dropped for room
        self.refused = 0
        self.dropped = 0
        self._logged = (0, 0)
        self._log_at = 0.0

    async def start(self, host: str, port: int, backlog: int = 128) -> int:
        """Listen on ``host``:``port``; the port bound (``port`` 0 takes a free one)."""
        self._loop = asyncio.get_running_loop()
        info = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                  flags=socket.AI_PASSIVE)[0]
        sock = socket.socket(info[0], socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(info[4])
            sock.listen(backlog)
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self._sock = sock
        self._loop.add_reader(sock.fileno(), self._accept)
        return int(sock.getsockname()[1])

    def close(self) -> None:
        """Stop listening; connections still being set up are dropped (the others are
        aiohttp's to close)."""
        if self._sock is not None and self._loop is not None:
            self._loop.remove_reader(self._sock.fileno())
            self._sock.close()
            self._sock = None
        for c in list(self.conns):
            if c.transport is None:
                c.drop()

    # -- requests (from the application's middleware) ----------------------------------
    def begin(self, transport: asyncio.BaseTransport | None) -> Conn | None:
        """A request of the connection ``transport`` is being handled."""
        c = self._by_transport.get(transport) if transport is not None else None
        if c is not None:
            c.busy += 1
        return c

    def end(self, c: Conn | None) -> None:
        """That request was handled: the connection is idle from now."""
        if c is not None:
            c.busy -= 1
            c.since = self.clock()

    # -- accepting ---------------------------------------------------------------------
    def _accept(self) -> None:
        assert self._sock is not None and self._loop is not None
        for _ in range(64):  # then the loop's other work
            try:
                sock, addr = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # out of descriptors or memory: wait, as asyncio does
                if exc.errno not in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS,
                                     errno.ENOMEM, errno.ECONNABORTED):
                    raise
                if exc.errno == errno.ECONNABORTED:
                    continue
                log.error("web: cannot accept a connection: %s (waiting %g s)",
                          exc.strerror, ACCEPT_RETRY_S)
                self._loop.remove_reader(self._sock.fileno())
                self._loop.call_later(ACCEPT_RETRY_S, self._resume)
                break
            self._admit(sock, str(addr[0]))
        self._note()

    def _resume(self) -> None:
        if self._sock is not None and self._loop is not None:
            self._loop.add_reader(self._sock.fileno(), self._accept)

    def _admit(self, sock: socket.socket, address: str) -> None:
        for c in [c for c in self.conns if c.closed()]:
            self._forget(c)
        mine = [c for c in self.conns if c.address == address]
        if len(mine) >= self.per_address and not self._make_room(mine):
            self.refused += 1
            sock.close()
            return
        if len(self.conns) >= self.total and not self._make_room(list(self.conns)):
            self.refused += 1
            sock.close()
            return
        sock.setblocking(False)
        c = Conn(address, self.clock())
        self.conns.add(c)
        assert self._loop is not None
        c.task = self._loop.create_task(self._connect(c, sock))

    def _make_room(self, among: list[Conn]) -> bool:
        """Drop the connection of ``among`` idle longest; False if none is idle."""
        idle = [c for c in among if c.busy == 0]
        if not idle:
            return False
        oldest = min(idle, key=lambda c: c.since)
        oldest.drop()
        self._forget(oldest)
        self.dropped += 1
        return True

    def _forget(self, c: Conn) -> None:
        self.conns.discard(c)
        if c.transport is not None:
            self._by_transport.pop(c.transport, None)

    async def _connect(self, c: Conn, sock: socket.socket) -> None:
        assert self._loop is not None
        try:
            transport, _protocol = await self._loop.connect_accepted_socket(
                self.factory, sock, ssl=self.ssl_context,
                ssl_handshake_timeout=HEADER_TIMEOUT_S if self.ssl_context else None)
        except (OSError, TimeoutError) as exc:  # a handshake refused or too slow
            log.debug("web: a connection from %s failed at its start: %s", c.address, exc)
            sock.close()
            self._forget(c)
            return
        except asyncio.CancelledError:  # dropped for room while its handshake went on
            sock.close()
            self._forget(c)
            raise
        if c not in self.conns:  # dropped meanwhile
            transport.abort()
            return
        c.transport = transport
        self._by_transport[transport] = c

    def _note(self) -> None:
        """The log line, at most once per LOG_EVERY_S, when connections were refused or
        dropped since the last one."""
        now = self.clock()
        if (self.refused, self.dropped) == self._logged or now < self._log_at:
            return
        log.warning("web: %d connections refused and %d idle ones dropped for room "
                    "(at most %d from one address, %d in all: docs/web.md)",
                    self.refused - self._logged[0], self.dropped - self._logged[1],
                    self.per_address, self.total)
        self._logged = (self.refused, self.dropped)
        self._log_at = now + LOG_EVERY_S
