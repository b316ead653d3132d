"""Modbus RTU line layer: one serial port, its timing, and its sharing between units.

``RtuMaster`` does request/reply transactions on one port (t3.5 silences, deadlines from
the baud rate, retries, resynchronisation). A port is one ``drivers.modbus_master.PollLink``
shared by the drivers of its units (one ``ModbusRtuDriver`` per unit), with one poll thread
that serves them in turn. ``SerialPorts`` owns the open lines of a process by port path:
the first driver of a port opens its line, the last one to leave closes it;
``shared_ports()`` is the one used by default, empty whenever no Modbus driver is open.

pyserial only opens and configures the port (raw, exclusive); the I/O is ``os.write`` and
``select``/``os.read`` on its descriptor.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import termios
import time
from dataclasses import dataclass

import serial

from drivers.base import DriverError
from drivers.modbus_frame import (
    READ_INPUT_REGISTERS,
    ModbusCrcError,
    ModbusError,
    ModbusFrameError,
    ModbusTimeout,
    check_reply,
    crc16,
    describe,
    reply_length,
    rtu_frame,
)
from drivers.modbus_master import Links, LinkStats, ModbusUnit, PollLink
from drivers.registry import MODBUS_RTU_KEYS

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SerialSettings:
    """What every driver sharing a port must agree on; the defaults are the declared ones
    (MODBUS_RTU_KEYS)."""

    port: str
    baudrate: int = MODBUS_RTU_KEYS["baudrate"].default
    parity: str = MODBUS_RTU_KEYS["parity"].default  # a pyserial parity: N, E, O
    stopbits: int = MODBUS_RTU_KEYS["stopbits"].default

    @property
    def char_s(self) -> float:
        """Time of one character on the wire (11 bits: start, 8 data, parity/stop, stop)."""
        return 11.0 / self.baudrate

    @property
    def t35_s(self) -> float:
        """Inter-frame silence: 3.5 characters, fixed 1.75 ms above 19200 baud."""
        return 0.00175 if self.baudrate > 19200 else 3.5 * self.char_s


class RtuMaster:
    """Request/reply transactions on one serial port; used by one thread at a time."""

    def __init__(self, settings: SerialSettings) -> None:
        self.settings = settings
        self.stats = LinkStats()
        self._serial: serial.Serial | None = None
        self._fd = -1
        self._last_traffic = 0.0  # time.monotonic() of the last byte seen or sent

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    def open(self) -> None:
        """Open and configure the port (raw, exclusive). OSError/SerialException on failure."""
        s = self.settings
        ser = serial.Serial(port=s.port, baudrate=s.baudrate, bytesize=8, parity=s.parity,
                            stopbits=s.stopbits, timeout=0, exclusive=True)
        self._serial = ser
        self._fd = ser.fileno()
        self._last_traffic = time.monotonic()

    def close(self) -> None:
        ser, self._serial = self._serial, None
        self._fd = -1
        if ser is not None:
            try:
                ser.close()
            except OSError:  # pragma: no cover - the device is already gone
                pass

    def transact(self, unit: int, pdu: bytes, timeout: float, retries: int) -> bytes:
        """Send ``pdu`` to ``unit``, return the checked normal reply PDU. Retries timeouts
        and damaged replies; an exception reply raises ModbusExceptionReply at once."""
        request = rtu_frame(unit, pdu)
        last: ModbusError | None = None
        for attempt in range(retries + 1):
            if attempt:
                self.stats.retries += 1
            try:
                reply = self._once(request, timeout)
            except ModbusTimeout as exc:
                self.stats.timeouts += 1
                last = exc
            except ModbusCrcError as exc:
                self.stats.crc_errors += 1
                last = exc
            except ModbusFrameError as exc:
                self.stats.frame_errors += 1
                last = exc
            else:
                if reply[1] & 0x80:
                    self.stats.exceptions += 1
                check_reply(unit, pdu, reply[1:-2])  # an exception reply raises here
                return reply[1:-2]
            self._resync(timeout)
        assert last is not None
        raise type(last)(f"{last} (after {retries + 1} attempts)")

    def _once(self, request: bytes, timeout: float) -> bytes:
        """One exchange: the reply frame, its unit, function, length and CRC checked (an
        exception reply is returned as it came)."""
        unit, function = request[0], request[1]
        pdu = request[1:-2]
        gap = self.settings.t35_s - (time.monotonic() - self._last_traffic)
        if gap > 0:
            time.sleep(gap)
        self._send(request)
        self.stats.requests += 1
        # ``timeout`` is the unit's time to answer: the wire time of our request and of its
        # full reply come on top (a 125-register reply is 255 bytes: 290 ms at 9600 baud)
        expected = reply_length(pdu) + 3
        deadline = (time.monotonic() + (len(request) + expected) * self.settings.char_s
                    + timeout)
        what = f"unit {unit}: FC {function} {describe(pdu)}"
        reply = self._read_exact(5, deadline, what)
        if reply[0] != unit or reply[1] & 0x7F != function:
            raise ModbusFrameError(f"{what}: reply from unit {reply[0]} FC {reply[1] & 0x7F}")
        if reply[1] & 0x80:
            if crc16(reply[:3]) != reply[3] | reply[4] << 8:
                raise ModbusCrcError(f"{what}: CRC error in exception reply")
            return reply
        if function <= READ_INPUT_REGISTERS and reply[2] != expected - 5:
            raise ModbusFrameError(f"{what}: byte count {reply[2]}, expected {expected - 5}")
        reply += self._read_exact(expected - 5, deadline, what)
        if crc16(reply[:-2]) != reply[-2] | reply[-1] << 8:
            raise ModbusCrcError(f"{what}: CRC error")
        if function > READ_INPUT_REGISTERS and reply[:6] != request[:6]:
            raise ModbusFrameError(f"{what}: reply does not echo the request")
        return reply

    def _send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._fd, view)
            except BlockingIOError:
                select.select([], [self._fd], [], 0.1)
                continue
            view = view[n:]
        self._last_traffic = time.monotonic()

    def _read_exact(self, n: int, deadline: float, what: str) -> bytes:
        buf = b""
        fd = self._fd
        while len(buf) < n:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                got = f"{len(buf)} of {n} bytes" if buf else "no reply"
                raise ModbusTimeout(f"{what}: timeout ({got})")
            ready, _, _ = select.select([fd], [], [], remaining)
            if ready:
                try:
                    chunk = os.read(fd, n - len(buf))
                except BlockingIOError:
                    continue
                if not chunk:
                    raise OSError(errno.EIO, f"{self.settings.port}: end of file")
                buf += chunk
                self._last_traffic = time.monotonic()
        return buf

    def _resync(self, timeout: float) -> None:
        """After a bad exchange: let the line fall silent for t3.5, drop what came."""
        fd, t35 = self._fd, self.settings.t35_s
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            ready, _, _ = select.select([fd], [], [], t35)
            if not ready:
                break
            try:
                if not os.read(fd, 256):
                    break
            except BlockingIOError:
                pass
            self._last_traffic = time.monotonic()
        termios.tcflush(fd, termios.TCIFLUSH)


class SerialPorts(Links):
    """The open serial lines, by port path: one ``PollLink`` per port, shared by the
    drivers of its units.

    A line lives from the first ``attach`` of its port to the last ``detach``: then its
    poll thread ends and the port is closed, so an instance is empty whenever none of its
    drivers is open. Drivers use ``shared_ports()`` unless given their own (a test may
    pass a fresh one). ``attach`` opens the port at once: DriverError if it cannot be
    opened, is already open under another name (``/dev/serial/by-id/...``), or is open
    with other settings."""

    def _new_link(self, driver: ModbusUnit) -> PollLink:
        settings: SerialSettings = driver.settings  # type: ignore[attr-defined]
        return PollLink(settings.port, settings, RtuMaster(settings),
                        f"modbus-rtu {settings.port}")

    def _check_new(self, driver: ModbusUnit, others: list[PollLink]) -> None:
        port = driver.link_key
        real = os.path.realpath(port)
        for other in others:  # another name of the same device (/dev/serial/by-id/...)?
            if os.path.realpath(other.key) == real:
                raise DriverError(f"{port} is {real}, already opened as {other.key}: name "
                                  "a shared port the same way in every driver")

    def ports(self) -> list[str]:
        """The paths of the open ports."""
        return self.keys()


_SHARED_PORTS = SerialPorts()


def shared_ports() -> SerialPorts:
    """The process's serial lines, shared by every Modbus driver not given its own
    ``SerialPorts``: two plants' drivers naming one port share its line (there is only
    one device). Empty whenever no such driver is open."""
    return _SHARED_PORTS
