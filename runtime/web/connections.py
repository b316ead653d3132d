"""The web view's listening socket and its connections, bounded (docs/web.md, "Bounds").

The server accepts its connections itself (``Listener``) so that it decides before a
connection costs more than its descriptor, TLS or not:

- **per address**: at most PER_ADDRESS connections from one address; more are closed as
  soon as accepted (an address that floods only refuses itself);
- **in all**: at most MAX_CONNECTIONS, and never more than the process's open-file limit
  allows (less NOFILE_RESERVE for the feed, the console sessions, the files it reads),
  so the server never runs out of descriptors (EMFILE: it could not accept anybody).
  When that bound is reached, a connection from an address that holds fewer than the
  address holding most takes the place of that address's connection idle longest (a
  connection is idle while no request of it is being handled: an open page, its
  WebSocket, never is): many addresses flooding at once cannot keep out one more;
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
from typing import Any

log = logging.getLogger(__name__)

#: a request's headers (and a TLS handshake, and a request's body) must arrive within, s
HEADER_TIMEOUT_S = 10.0
#: connections at once, in all
MAX_CONNECTIONS = 512
#: connections at once from one address (a browser opens 6 to a server, plus one per
#: page; behind an SSH tunnel every browser is 127.0.0.1)
PER_ADDRESS = 64
#: descriptors kept for the rest of the process (the feed, console sessions, files)
NOFILE_RESERVE = 64
#: connections the system queues until they are accepted (a flood that fills the queue
#: leaves the others' connections waiting for the system's retries, 1 s, 3 s, 7 s...)
BACKLOG = 1024
#: connections accepted in one turn of the event loop (then the pages' own work)
ACCEPT_BATCH = 64
#: the refusals are logged at most this often, s
LOG_EVERY_S = 10.0
#: after the system refused an accept (out of descriptors or memory), accepting waits, s
ACCEPT_RETRY_S = 1.0


def total_bound(limit: int | None = None) -> int:
    """``limit`` (MAX_CONNECTIONS), or fewer when the open-file limit (RLIMIT_NOFILE)
    would not hold them beside NOFILE_RESERVE."""
    limit = MAX_CONNECTIONS if limit is None else limit
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
    #: its set-up (the TLS handshake) until its transport is made
    task: asyncio.Task[None] | None = None

    def drop(self) -> None:
        """Close it at once (what it was sending is lost)."""
        if self.transport is not None:
            abort = getattr(self.transport, "abort", None)
            if abort is not None:
                abort()
            else:
                self.transport.close()
        elif self.task is not None:
            self.task.cancel()


class Counted(asyncio.Protocol):
    """aiohttp's protocol for one connection, the Listener told when the connection ends
    (every call passed on as it is)."""

    def __init__(self, inner: asyncio.Protocol, lost: Callable[[], None]) -> None:
        self.inner, self._lost = inner, lost

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.inner.connection_made(transport)

    def connection_lost(self, exc: Exception | None) -> None:
        self._lost()
        self.inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received()

    def pause_writing(self) -> None:
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        self.inner.resume_writing()


class Listener:
    """A listening TCP socket whose connections go to ``factory`` (aiohttp's server),
    within the bounds of the module docstring."""

    def __init__(self, factory: Callable[[], Any], ssl_context: ssl.SSLContext | None,
                 total: int | None = None, per_address: int | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.factory = factory
        self.ssl_context = ssl_context
        self.total = total_bound() if total is None else total
        self.per_address = PER_ADDRESS if per_address is None else per_address
        self.clock = clock
        #: address -> its connections
        self.by_address: dict[str, set[Conn]] = {}
        self.count = 0
        self._by_transport: dict[asyncio.BaseTransport, Conn] = {}
        self._sock: socket.socket | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        #: counters (tests, the log line): connections refused, and dropped for room
        self.refused = 0
        self.dropped = 0
        self._logged = (0, 0)
        self._log_at = 0.0

    async def start(self, host: str, port: int, backlog: int = BACKLOG) -> int:
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
        for conns in list(self.by_address.values()):
            for c in list(conns):
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
        for _ in range(ACCEPT_BATCH):
            try:
                sock, addr = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionAbortedError:
                continue
            except OSError as exc:  # out of descriptors or memory: wait, as asyncio does
                if exc.errno not in (errno.EMFILE, errno.ENFILE, errno.ENOBUFS,
                                     errno.ENOMEM):
                    raise
                log.error("web: cannot accept a connection: %s (waiting %g s)",
                          exc.strerror, ACCEPT_RETRY_S)
                self._loop.remove_reader(self._sock.fileno())
                self._loop.call_later(ACCEPT_RETRY_S, self._resume)
                break
            if self._room(str(addr[0])):
                self._admit(sock, str(addr[0]))
            else:
                self.refused += 1
                sock.close()
        self._note()

    def _resume(self) -> None:
        if self._sock is not None and self._loop is not None:
            self._loop.add_reader(self._sock.fileno(), self._accept)

    def _room(self, address: str) -> bool:
        """Whether a new connection from ``address`` may be served (after dropping,
        if the total is reached, an idle one of the address holding most)."""
        mine = len(self.by_address.get(address, ()))
        if mine >= self.per_address:
            return False
        if self.count < self.total:
            return True
        most = max(self.by_address.values(), key=len)
        if mine + 1 >= len(most):  # it would hold as many: no fairer that way
            return False
        idle = [c for c in most if c.busy == 0]
        if not idle:
            return False
        oldest = min(idle, key=lambda c: c.since)
        self._forget(oldest)
        oldest.drop()
        self.dropped += 1
        return True

    def _admit(self, sock: socket.socket, address: str) -> None:
        assert self._loop is not None
        sock.setblocking(False)
        c = Conn(address, self.clock())
        self.by_address.setdefault(address, set()).add(c)
        self.count += 1
        c.task = self._loop.create_task(self._connect(c, sock))

    def _forget(self, c: Conn) -> None:
        conns = self.by_address.get(c.address)
        if conns is None or c not in conns:
            return
        conns.discard(c)
        if not conns:
            del self.by_address[c.address]
        self.count -= 1
        if c.transport is not None:
            self._by_transport.pop(c.transport, None)

    async def _connect(self, c: Conn, sock: socket.socket) -> None:
        assert self._loop is not None
        try:
            transport, _protocol = await self._loop.connect_accepted_socket(
                lambda: Counted(self.factory(), lambda: self._forget(c)), sock,
                ssl=self.ssl_context,
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
        if c not in self.by_address.get(c.address, ()):  # dropped, or lost, meanwhile
            if not transport.is_closing():
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
