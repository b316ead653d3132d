"""Modbus TCP master driver: one unit's points on a device or gateway reached over TCP,
polled off the scan.

The same contract and points as modbus_rtu (``drivers.modbus_master.ModbusUnit``: ``I``
discrete inputs, ``Q`` coils, ``IR`` input registers, ``HR`` holding registers, 16-bit
registers as the unit holds them), the same PDU layer (``drivers.modbus_frame``); what is
new is the transport: ``TcpMaster`` sends each PDU behind its MBAP header on one TCP
connection and matches the reply by transaction id. Several drivers naming the same
``host`` and ``port`` are the units behind one gateway (a Modbus TCP to RTU gateway, a
remote I/O coupler with several modules): they share one connection and one poll thread
(``Gateways``), served in turn as the units of a serial line are.

The connection is made by the poll thread, never by the scan: at ``open()`` the driver
waits for the first exchange as any polled driver does, and a refused or lost connection
is a fault of every unit behind it, tried again at the units' back-off times (0.1 s
doubling to 5 s). ``timeout`` is one request's: a unit that does not answer in time (or
a gateway's exception 0x0B for a unit it cannot reach) is that unit's fault only, and a
reply that comes after its timeout is recognised by its transaction id and dropped. A
reply cut short (the connection reset in the middle of a frame) or a stream that is no
Modbus/TCP closes the connection.

Config::

    rio: {type: modbus_tcp, host: 192.168.10.20, port: 502, unit: 1, timeout: 200ms,
          retries: 1}
"""

from __future__ import annotations

import itertools
import select
import socket
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from drivers.modbus_frame import (
    MAX_PDU,
    MBAP_SIZE,
    ModbusError,
    ModbusExceptionReply,
    ModbusFrameError,
    ModbusTimeout,
    check_reply,
    describe,
    mbap_frame,
    mbap_header,
)
from drivers.modbus_master import Links, LinkStats, ModbusUnit, PollLink
from drivers.registry import MODBUS_TCP_KEYS


@dataclass(frozen=True)
class TcpSettings:
    """Where a gateway is: every unit behind it names the same host and port."""

    host: str
    port: int

    @property
    def key(self) -> str:
        """``host:port`` (``[address]:port`` for an IPv6 address)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{host}:{self.port}"


class TcpMaster:
    """Request/reply transactions on one TCP connection; used by one thread at a time."""

    #: the longest wait for a connection, seconds
    CONNECT_TIMEOUT_S: ClassVar[float] = 2.0

    def __init__(self, settings: TcpSettings) -> None:
        self.settings = settings
        self.stats = LinkStats()
        self._sock: socket.socket | None = None
        self._ids = itertools.count(1)

    @property
    def is_open(self) -> bool:
        return self._sock is not None

    def open(self) -> None:
        """Connect (TCP_NODELAY, keep-alive); OSError naming what failed."""
        s = self.settings
        sock = socket.create_connection((s.host, s.port), timeout=self.CONNECT_TIMEOUT_S)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
        sock.setblocking(False)
        self._sock = sock

    def close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()

    def transact(self, unit: int, pdu: bytes, timeout: float, retries: int) -> bytes:
        """Send ``pdu`` to ``unit``, return the checked normal reply PDU. Retries timeouts
        and damaged replies; an exception reply raises ModbusExceptionReply at once; a
        connection that fails raises OSError (the caller closes it)."""
        last: ModbusError | None = None
        for attempt in range(retries + 1):
            if attempt:
                self.stats.retries += 1
            try:
                return self._once(unit, pdu, timeout)
            except ModbusExceptionReply:
                self.stats.exceptions += 1
                raise
            except ModbusTimeout as exc:
                self.stats.timeouts += 1
                last = exc
            except ModbusFrameError as exc:
                self.stats.frame_errors += 1
                last = exc
        assert last is not None
        raise type(last)(f"{last} (after {retries + 1} attempts)")

    def _once(self, unit: int, pdu: bytes, timeout: float) -> bytes:
        tid = next(self._ids) & 0xFFFF
        what = f"unit {unit}: FC {pdu[0]} {describe(pdu)}"
        self._send(mbap_frame(tid, unit, pdu), timeout, what)
        self.stats.requests += 1
        deadline = time.monotonic() + timeout
        while True:
            header = self._read(MBAP_SIZE, deadline, what, cut=False)
            got_tid, protocol, length, got_unit = mbap_header(header)
            if protocol != 0 or not 1 <= length <= MAX_PDU:
                raise ConnectionError(f"{what}: not a Modbus/TCP reply (protocol "
                                                    f"{protocol}, length {length + 1})")
            # a frame begun is given a whole timeout to end, whenever its header came
            reply = self._read(length, max(deadline, time.monotonic() + timeout), what,
                               cut=True)
            if got_tid != tid:  # the late reply of an earlier, timed-out transaction
                self.stats.late_replies += 1
                continue
            if got_unit != unit:
                raise ModbusFrameError(f"{what}: reply from unit {got_unit}")
            check_reply(unit, pdu, reply)
            return reply

    def _send(self, data: bytes, timeout: float, what: str) -> None:
        sock = self._sock
        if sock is None:
            raise ConnectionError("not connected")
        view = memoryview(data)
        deadline = time.monotonic() + timeout
        while view:
            try:
                n = sock.send(view)
            except BlockingIOError:
                remaining = deadline - time.monotonic()
                if remaining <= 0:  # the peer reads nothing: the connection is unusable
                    raise ConnectionError(f"{what}: the request could not "
                                                           "be sent") from None
                select.select([], [sock], [], remaining)
                continue
            view = view[n:]

    def _read(self, n: int, deadline: float, what: str, cut: bool) -> bytes:
        """``n`` bytes by ``deadline``; ModbusTimeout if none came (``cut`` False), an
        OSError if the connection ends or the frame was started and not finished in time
        (the stream is then out of step: the connection is closed)."""
        sock = self._sock
        if sock is None:
            raise ConnectionError("not connected")
        buf = b""
        while len(buf) < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                if buf or cut:
                    raise ConnectionError(f"{what}: reply cut short "
                                                           f"({len(buf)} of {n} bytes)")
                raise ModbusTimeout(f"{what}: timeout (no reply)")
            ready, _, _ = select.select([sock], [], [], remaining)
            if not ready:
                continue
            try:
                chunk = sock.recv(n - len(buf))
            except BlockingIOError:
                continue
            if not chunk:
                raise ConnectionResetError("connection closed by the peer")
            buf += chunk
        return buf


class Gateways(Links):
    """The open TCP connections, by ``host:port``: one ``PollLink`` per gateway, shared by
    the drivers of the units behind it. A connection is made by its poll thread, never in
    ``attach`` (the scan thread at a recovery)."""

    OPEN_AT_ATTACH = False

    def _new_link(self, driver: ModbusUnit) -> PollLink:
        settings: TcpSettings = driver.settings  # type: ignore[attr-defined]
        return PollLink(settings.key, settings, TcpMaster(settings),
                        f"modbus-tcp {settings.key}", verb="connect")


_SHARED_GATEWAYS = Gateways()


def shared_gateways() -> Gateways:
    """The process's TCP connections, shared by every modbus_tcp driver not given its own
    ``Gateways``. Empty whenever no such driver is open."""
    return _SHARED_GATEWAYS


class ModbusTcpDriver(ModbusUnit):
    """One Modbus unit on a device or gateway reached over TCP."""

    type_name = "modbus_tcp"
    config_keys = MODBUS_TCP_KEYS

    def __init__(
        self,
        name: str,
        config: Mapping[str, Any] | None = None,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
        gateways: Gateways | None = None,
    ) -> None:
        #: the open connections this driver's gateway is shared through (default: the
        #: process's)
        self.gateways = shared_gateways() if gateways is None else gateways
        super().__init__(name, config, clock=clock)

    def _init(self) -> None:
        super()._init()
        p = self.params
        self.settings = TcpSettings(p["host"], p["port"])
        self.unit, self.timeout_s, self.retries = p["unit"], p["timeout"], p["retries"]
        self.links, self.link_key = self.gateways, self.settings.key
        self._stale_after()
