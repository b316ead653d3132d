"""The plant's Modbus/TCP server: its own process, fed by the controller's feed socket
(runtime/controller/feed.py), never in the scan's way; asyncio and the project's own PDU
layer (drivers/modbus_frame.py), no Modbus library (docs/modbus.md says why).

- Values: every frame of the feed refreshes the four tables (``tables.Tables``); a read is
  answered from the last frame. Without values (the feed not connected, or the controller
  not writing its shared image for ``stale_after_s`` by its own stamp in the image's
  header, or, without an image, no frame for that long: the controller stopped, frozen or
  stuck in a scan; this process's event loop being busy never counts) every request is
  answered with exception 11 (gateway target device failed to respond): a panel shows a
  communication error, never old values as good.
- Writes: only to the names of ``modbus: writable:`` (coils, holding registers), carried to
  the controller through the feed and applied between two scans; the reply is sent once
  the controller answered, and each write is logged with the client's address. Any other
  write is answered with an exception (docs/modbus.md, "Exceptions").
- Who may connect: ``modbus: clients:`` (addresses or networks), at most ``limits:
  connections`` at once; on the TLS listener (Modbus/TCP Security) a certificate signed by
  ``tls: clients_ca``, whose role (runtime/modbus/security.py) says read or write.
- Hostile input: a header that is no Modbus/TCP (protocol id not 0, a length past 253), a
  frame cut short, a connection idle past ``limits: idle``, a client that does not read its
  replies: the connection is closed with one log line. A request the server does not serve
  (a function code, a quantity out of range, an address no name has) is answered with its
  exception; the first of each kind per connection is logged, the others counted in the
  connection's last line. A connection asking more than ``limits: rate`` requests a second
  is paced (its requests wait), never the others.
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drivers.modbus_frame import (
    GATEWAY_TARGET_FAILED,
    ILLEGAL_DATA_VALUE,
    ILLEGAL_FUNCTION,
    MAX_PDU,
    MBAP_SIZE,
    SERVER_DEVICE_FAILURE,
    Request,
    RequestError,
    exception_pdu,
    mbap_frame,
    mbap_header,
    parse_request,
    read_reply,
    write_reply,
)
from runtime.controller.aio import within
from runtime.controller.feedclient import FeedClient, FeedLost
from runtime.language import ast as A
from runtime.language.modbusconf import name_type
from runtime.language.model import ModbusDef, PlantDef
from runtime.modbus.security import DerError, role_of, server_context
from runtime.modbus.tables import Tables

log = logging.getLogger(__name__)

#: the table each function code reads or writes
TABLE_OF = {1: "Q", 2: "I", 3: "HR", 4: "IR", 5: "Q", 15: "Q", 6: "HR", 16: "HR"}
#: a write the controller has not answered in this long fails (exception 11), seconds
WRITE_TIMEOUT_S = 2.0
#: values are stale when no frame came for this many samples, and at least STALE_MIN_S
STALE_SAMPLES = 4
STALE_MIN_S = 1.0
#: the rest of a frame whose header came must come within this, seconds
FRAME_TIMEOUT_S = 5.0
#: replies a client leaves unread are dropped with it after this, seconds
SEND_TIMEOUT_S = 5.0
#: unsent bytes of one connection before the server waits for the client to read
WRITE_HIGH = 64 * 1024
#: the kernel's send buffer of a connection, bytes (fixed: autotuned, it would take
#: megabytes of replies before a client that reads none is seen)
SEND_BUFFER = 64 * 1024
#: a TLS handshake must end within this, seconds
HANDSHAKE_TIMEOUT_S = 10.0
#: the feed's answer code -> the exception of a refused write
REFUSED_CODE = {"BadInvalidArgument": ILLEGAL_DATA_VALUE, "BadTimeout": GATEWAY_TARGET_FAILED,
                "BadNoCommunication": GATEWAY_TARGET_FAILED}


def stale_after_s(sample_ns: int) -> float:
    """How long without a frame makes the values stale, seconds."""
    return max(STALE_SAMPLES * sample_ns / 1e9, STALE_MIN_S)


@dataclass(slots=True)
class Connection:
    """One client's connection: who, what it may do, what it was refused."""

    who: str
    may_read: bool = True
    may_write: bool = True
    #: the role of its certificate (TLS), "" on the plain listener
    role: str = ""
    requests: int = 0
    writes: int = 0
    #: kind of refusal -> how many (the first of each kind is logged)
    refused: dict[str, int] = field(default_factory=dict)
    #: the pacing bucket: requests it may still make at once, and when it was filled
    tokens: float = 0.0
    filled: float = 0.0
    paced: bool = False

    def refuse(self, kind: str, text: str) -> None:
        """Count a refusal; its first of ``kind`` is one log line (the log's rate limit
        counts each kind apart: its template names it)."""
        n = self.refused.get(kind, 0)
        self.refused[kind] = n + 1
        if n == 0:
            log.warning("modbus: %s: " + kind.replace("%", "%%") + ": %s", self.who, text)


class ModbusServer:
    """``softplc modbus PLANT``: serve the plant's image from its feed over Modbus/TCP."""

    def __init__(self, pdef: PlantDef, feed: str | None = None,
                 listen: tuple[str, int] | None = None) -> None:
        assert pdef.modbus is not None
        self.pdef = pdef
        self.conf: ModbusDef = pdef.modbus
        self.listen = listen or (self.conf.host, self.conf.port)
        self.feed_path = feed or self.conf.feed
        self.tables = Tables(self.conf.points, self.conf.words, _time_names(pdef))
        self.writable = set(self.conf.writable)
        self.feed = FeedClient(self.feed_path, "modbus", self._schema, self._frame,
                               self._lost, plant=pdef)
        self.state = self.feed.state
        self._networks = [ipaddress.ip_network(c) for c in self.conf.clients]
        self._servers: list[asyncio.Server] = []
        self._tls: ssl.SSLContext | None = None
        self._connections: set[asyncio.Task[None]] = set()
        self._last_frame: float | None = None
        self._stale_after = stale_after_s(self.conf.sample_ns)
        self._missing: list[str] = []
        #: frames applied, requests answered (tests, the bench)
        self.frames = 0
        self.requests = 0
        #: the ports listened on: plain, then TLS (0: none)
        self.ports: tuple[int, int] = (0, 0)

    # -- set-up ------------------------------------------------------------------------
    async def start(self) -> None:
        """Listen (plain and TLS as the plant says). OSError if a port cannot be had."""
        host, port = self.listen
        plain = tls = 0
        if host:  # (port 0: a free port, for the tests)
            srv = await asyncio.start_server(self._plain_client, host, port,
                                             limit=MAX_PDU + MBAP_SIZE)
            self._servers.append(srv)
            plain = srv.sockets[0].getsockname()[1]
            log.info("Modbus/TCP server on %s:%d (feed %s)", host, plain, self.feed_path)
        t = self.conf.tls
        if t is not None:
            self._tls = server_context(t)
            # TLS is started by the connection's handler, after the allow-list and the
            # limit: a handshake that fails is then its one log line
            srv = await asyncio.start_server(self._tls_client, t.host, t.port,
                                             limit=MAX_PDU + MBAP_SIZE)
            self._servers.append(srv)
            tls = srv.sockets[0].getsockname()[1]
            log.info("Modbus/TCP Security server on %s:%d (roles: %s)", t.host, tls,
                     ", ".join(f"{r} {m}" for r, m in t.roles.items()))
        self.ports = (plain, tls)

    async def run(self) -> None:
        """Follow the feed until ``stop()``."""
        await self.feed.run()

    def stop(self) -> None:
        self.feed.stop()

    async def close(self) -> None:
        for srv in self._servers:
            srv.close()
        for task in list(self._connections):
            task.cancel()
        await asyncio.gather(*self._connections, return_exceptions=True)
        for srv in self._servers:
            await srv.wait_closed()

    # -- the feed ----------------------------------------------------------------------
    async def _schema(self, schema: dict[str, Any]) -> None:
        self._last_frame = None
        names = {n[0] for n in schema["names"]}
        missing = [pt.name for pt in self.conf.points if pt.name not in names]
        if missing != self._missing:
            self._missing = missing
            if missing:
                log.warning("modbus: the controller's plant has no %s: answered as 0 until "
                            "it has (is it running another plant file?)", ", ".join(missing))

    async def _frame(self) -> None:
        st = self.state
        index, values = st.index, st.values

        def get(name: str) -> Any:
            i = index.get(name)
            return values[i] if i is not None else 0
        for name, value, clipped in self.tables.refresh(get):
            if clipped:
                log.warning("modbus: %s = %s does not fit its type in the map: sent as the "
                            "nearest value it can hold until it does", name, value)
            else:
                log.info("modbus: %s fits its type in the map again", name)
        if self._last_frame is None or not self.fresh():
            log.info("modbus: values from the controller (scan %d)", st.scan)
        self._last_frame = time.monotonic()
        self.frames += 1

    async def _lost(self) -> None:
        self._last_frame = None

    def fresh(self) -> bool:
        """The tables hold the controller's values: a frame came since the feed's schema,
        and the controller wrote its shared image within ``stale_after_s`` (its own
        monotonic stamp: ``FeedClient.controller_age_s``; this event loop being busy never
        counts), or, without an image, a frame came within that time."""
        last = self._last_frame
        if last is None:
            return False
        age = self.feed.controller_age_s()
        if age is not None:
            return age <= self._stale_after
        return time.monotonic() - last <= self._stale_after

    # -- clients -----------------------------------------------------------------------
    async def _plain_client(self, reader: asyncio.StreamReader,
                            writer: asyncio.StreamWriter) -> None:
        await self._client(reader, writer, False)

    async def _tls_client(self, reader: asyncio.StreamReader,
                          writer: asyncio.StreamWriter) -> None:
        await self._client(reader, writer, True)

    async def _handshake(self, writer: asyncio.StreamWriter, who: str) -> str | None:
        """TLS on the connection; the role of the client's certificate ("" without one),
        or None if the handshake failed (one log line)."""
        assert self._tls is not None
        try:
            await writer.start_tls(self._tls, ssl_handshake_timeout=HANDSHAKE_TIMEOUT_S)
        except (ssl.SSLError, ConnectionError, TimeoutError, OSError) as exc:
            reason = getattr(exc, "reason", None) or str(exc) or type(exc).__name__
            log.warning("modbus: TLS connection from %s refused: %s", who, reason)
            return None
        sslobj = writer.get_extra_info("ssl_object")
        der = sslobj.getpeercert(binary_form=True) if sslobj is not None else None
        try:
            return (role_of(der) if der else None) or ""
        except DerError:
            return ""

    def _allowed(self, host: str) -> bool:
        if not self._networks:
            return True
        try:
            addr = ipaddress.ip_address(host)
        except ValueError:
            return False
        if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
            addr = addr.ipv4_mapped
        return any(addr in net for net in self._networks)

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                      tls: bool) -> None:
        peer = writer.get_extra_info("peername") or ("?", 0)
        host, port = str(peer[0]), int(peer[1])
        who = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        task = asyncio.current_task()
        if not self._allowed(host):
            log.warning("modbus: connection from %s refused: not in modbus: clients", who)
            writer.close()
            return
        if len(self._connections) >= self.conf.limits.connections:
            log.warning("modbus: connection from %s refused: %d connections already "
                        "(modbus: limits: connections)", who, len(self._connections))
            writer.close()
            return
        assert task is not None
        self._connections.add(task)
        role = None
        if tls:
            role = await self._handshake(writer, who)
            if role is None:
                self._connections.discard(task)
                writer.close()
                return
        c = Connection(who, tokens=float(self.conf.limits.rate), filled=time.monotonic())
        if role is not None:  # the TLS listener: the certificate's role decides
            c.role = role
            may = self.conf.tls.roles.get(role) if self.conf.tls is not None else None
            c.may_read = may in ("read", "write")
            c.may_write = may == "write"
            log.info("modbus: %s connected over TLS, role %s: %s", who, role or "(none)",
                     may or "no access")
        else:
            log.info("modbus: %s connected", who)
        transport = writer.transport
        transport.set_write_buffer_limits(high=WRITE_HIGH)
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
        why = "closed by the client"
        try:
            why = await self._serve(c, reader, writer)
        except (ConnectionError, ssl.SSLError, OSError) as exc:
            why = f"connection error: {exc}"
        finally:
            self._connections.discard(task)
            writer.close()
            refused = ", ".join(f"{k} x{n}" for k, n in c.refused.items())
            log.info("modbus: %s gone (%s) after %d requests, %d writes%s", who, why,
                     c.requests, c.writes, f"; refused: {refused}" if refused else "")

    async def _serve(self, c: Connection, reader: asyncio.StreamReader,
                     writer: asyncio.StreamWriter) -> str:
        """Serve one connection's requests until it ends; why it ended."""
        idle = self.conf.limits.idle_ns / 1e9
        transport = writer.transport
        while True:
            try:
                header = await within(reader.readexactly(MBAP_SIZE), idle)
            except TimeoutError:
                log.info("modbus: %s idle for %g s: closed", c.who, idle)
                return "idle"
            except asyncio.IncompleteReadError as exc:
                if exc.partial:
                    log.warning("modbus: %s: a header cut short (%d of %d bytes): closed",
                                c.who, len(exc.partial), MBAP_SIZE)
                    return "a header cut short"
                return "closed by the client"
            tid, protocol, length, unit = mbap_header(header)
            if protocol != 0:
                log.warning("modbus: %s: an MBAP header with protocol id %d (Modbus is 0): "
                            "not Modbus/TCP, closed", c.who, protocol)
                return "not Modbus/TCP"
            if not 1 <= length <= MAX_PDU:
                log.warning("modbus: %s: an MBAP length of %d (2 to %d): closed", c.who,
                            length + 1, MAX_PDU + 1)
                return "a length that lies"
            try:
                pdu = await within(reader.readexactly(length), FRAME_TIMEOUT_S)
            except (TimeoutError, asyncio.IncompleteReadError):
                log.warning("modbus: %s: a frame of %d bytes announced, not sent within "
                            "%g s: closed", c.who, length, FRAME_TIMEOUT_S)
                return "a frame cut short"
            await self._pace(c)
            c.requests += 1
            self.requests += 1
            reply = await self._answer(c, unit, pdu)
            writer.write(mbap_frame(tid, unit, reply))
            if transport.get_write_buffer_size() > WRITE_HIGH:
                try:
                    await within(writer.drain(), SEND_TIMEOUT_S)
                except TimeoutError:
                    log.warning("modbus: %s reads no replies (%d bytes waiting for %g s): "
                                "dropped", c.who, transport.get_write_buffer_size(),
                                SEND_TIMEOUT_S)
                    transport.abort()  # its replies discarded, the connection reset
                    return "it read no replies"

    async def _pace(self, c: Connection) -> None:
        """At most ``limits: rate`` requests a second, in bursts of as many."""
        rate = self.conf.limits.rate
        now = time.monotonic()
        c.tokens = min(float(rate), c.tokens + (now - c.filled) * rate)
        c.filled = now
        if c.tokens < 1.0:
            if not c.paced:
                c.paced = True
                log.warning("modbus: %s asks more than %d requests a second: paced "
                            "(modbus: limits: rate)", c.who, rate)
            await asyncio.sleep((1.0 - c.tokens) / rate)
            c.tokens = 1.0
            c.filled = time.monotonic()
        c.tokens -= 1.0

    async def _answer(self, c: Connection, unit: int, pdu: bytes) -> bytes:
        """The reply PDU to request ``pdu``."""
        function = pdu[0] & 0x7F
        if self.conf.unit is not None and unit != self.conf.unit:
            c.refuse("exception 11", f"unit {unit} asked: this server is unit "
                                     f"{self.conf.unit}")
            return exception_pdu(function, GATEWAY_TARGET_FAILED)
        try:
            req = parse_request(pdu)
        except RequestError as exc:
            c.refuse(f"exception {exc.code} to FC {pdu[0]}", str(exc))
            return exception_pdu(function, exc.code)
        if not (c.may_write if req.writes else c.may_read):
            what = "write" if req.writes else "read"
            c.refuse(f"exception 1 to FC {req.function}", f"role '{c.role}' may not {what}")
            return exception_pdu(function, ILLEGAL_FUNCTION)
        if not self.fresh():
            c.refuse("exception 11", "no values from the controller (stopped, or no feed)")
            return exception_pdu(function, GATEWAY_TARGET_FAILED)
        table = TABLE_OF[req.function]
        try:
            if not req.writes:
                return read_reply(req, self.tables.read(table, req.address, req.count))
            writes = self.tables.writes(table, req.address, list(req.values),
                                        self.writable.__contains__)
        except RequestError as exc:
            c.refuse(f"exception {exc.code} to FC {req.function}", str(exc))
            return exception_pdu(function, exc.code)
        return await self._write(c, req, pdu, writes)

    async def _write(self, c: Connection, req: Request, pdu: bytes, writes: list[Any]
                     ) -> bytes:
        """Each name set through the controller, together (one scan boundary); the echo if
        all were applied, else the exception of the first refusal."""
        async def one(name: str, value: Any) -> tuple[bool, str, str]:
            try:
                return await self.feed.ask("set", name, value, "modbus",
                                           timeout=WRITE_TIMEOUT_S)
            except TimeoutError:
                return False, "the controller did not answer in time", "BadTimeout"
            except (OSError, FeedLost):
                return False, "no connection to the controller", "BadNoCommunication"
        answers = await asyncio.gather(*(one(w.name, w.value) for w in writes))
        code = 0
        for w, (ok, text, status) in zip(writes, answers, strict=True):
            if ok:
                c.writes += 1
                log.info("modbus: %s%s set %s", c.who, f" (role {c.role})" if c.role else "",
                         text.replace(" set to ", " = "))
            else:
                log.warning("modbus: %s: write of %s refused by the controller: %s", c.who,
                            w.name, text)
                code = code or REFUSED_CODE.get(status, SERVER_DEVICE_FAILURE)
        if code:
            return exception_pdu(req.function, code)
        return write_reply(pdu)


def _time_names(pdef: PlantDef) -> set[str]:
    """The mapped names whose plant type is TIME (a step's .T, a time variable)."""
    assert pdef.modbus is not None
    return {pt.name for pt in pdef.modbus.points if name_type(pdef, pt.name) is A.Type.TIME}


async def serve(pdef: PlantDef, feed: str | None = None,
                listen: tuple[str, int] | None = None,
                ready: Callable[[ModbusServer], None] | None = None,
                stop: asyncio.Event | None = None) -> None:
    """Run the server until ``stop`` is set (or forever). OSError if it cannot listen."""
    ms = ModbusServer(pdef, feed, listen)
    await ms.start()
    task = asyncio.create_task(ms.run())
    if ready is not None:
        ready(ms)
    try:
        if stop is None:
            await task
        else:  # until stop, or the feed's end (a feed refused: feedclient.ForeignFeed)
            waiter = asyncio.ensure_future(stop.wait())
            await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
            waiter.cancel()
            ms.stop()
            await task
    finally:
        await ms.close()
