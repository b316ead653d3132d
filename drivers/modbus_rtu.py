"""Modbus RTU master on a serial line (pyserial), polled off the scan by one thread per port.

Why our own small master rather than pymodbus' client: a request through pymodbus' sync
client costs 2 ms or more on a pseudo-terminal (asyncio machinery on every call), and we
need exact control of the response timeout, of retries and of the inter-frame gap; the
part of Modbus RTU a PLC master needs (function codes 1, 2, 3, 4, 5, 6, 15, 16) is small
enough to carry. The wire format follows the Modbus over Serial Line specification v1.02:
CRC-16 (polynomial 0xA001, low byte first), t3.5 of silence between frames (1.75 ms above
19200 baud), exception replies with the function code's high bit set.

Several drivers (one per slave *unit*) may share a port: they share one ``SerialLine``
keyed by the port path, whose thread polls the units in turn, one round per scan
(``write()`` wakes it); each round first writes the outputs that changed, then reads the
bound inputs in as few requests as the addresses allow. A unit that fails is skipped by
later rounds until the scan asks for a retry (back-off in ``drivers.base``), so a dead
unit does not slow its neighbours down.

Points: ``I0``... discrete inputs (FC 2), ``Q0``... coils (written with FC 5/15, or read
with FC 1 when bound as an input), ``IR0``... input registers (FC 4), ``HR0``... holding
registers (written with FC 6/16, or read with FC 3). Numbers are protocol addresses, from 0.
Config::

    mb: {type: modbus_rtu, port: /dev/ttyUSB0, baudrate: 115200, parity: E, unit: 1,
         timeout: 100ms, retries: 2}
"""

from __future__ import annotations

import errno
import logging
import os
import re
import select
import termios
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import serial

from drivers.base import (
    ConfigError,
    Direction,
    DriverError,
    PointError,
    PointKind,
    PolledDriver,
    parse_duration,
)
from drivers.config import MODBUS_RTU_KEYS

log = logging.getLogger(__name__)

# -- protocol: pure encoding and decoding ---------------------------------------------------

READ_COILS, READ_DISCRETE_INPUTS, READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS = 1, 2, 3, 4
WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER = 5, 6
WRITE_MULTIPLE_COILS, WRITE_MULTIPLE_REGISTERS = 15, 16

#: most items one request may carry, by function code (Modbus application protocol v1.1b3)
MAX_ITEMS = {1: 2000, 2: 2000, 3: 125, 4: 125, 15: 1968, 16: 123}

EXCEPTION_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Modbus CRC-16 of ``data`` (sent low byte first)."""
    crc = 0xFFFF
    table = _CRC_TABLE
    for b in data:
        crc = (crc >> 8) ^ table[(crc ^ b) & 0xFF]
    return crc


def frame(body: bytes) -> bytes:
    """``body`` (unit, function, data) with its CRC appended."""
    crc = crc16(body)
    return body + bytes((crc & 0xFF, crc >> 8))


def read_request(unit: int, function: int, address: int, count: int) -> bytes:
    """A read request (FC 1-4) for ``count`` items from ``address``."""
    return frame(bytes((unit, function, address >> 8, address & 0xFF, count >> 8, count & 0xFF)))


def write_coils_request(unit: int, address: int, bits: list[int]) -> bytes:
    """FC 5 for one coil, FC 15 for several."""
    if len(bits) == 1:
        value = 0xFF00 if bits[0] else 0x0000
        return frame(bytes((unit, WRITE_SINGLE_COIL, address >> 8, address & 0xFF,
                            value >> 8, value & 0xFF)))
    packed = bytearray((len(bits) + 7) // 8)
    for i, bit in enumerate(bits):
        if bit:
            packed[i // 8] |= 1 << (i % 8)
    n = len(bits)
    return frame(bytes((unit, WRITE_MULTIPLE_COILS, address >> 8, address & 0xFF, n >> 8,
                        n & 0xFF, len(packed))) + bytes(packed))


def write_registers_request(unit: int, address: int, values: list[int]) -> bytes:
    """FC 6 for one register, FC 16 for several; values are taken modulo 2**16."""
    regs = [v & 0xFFFF for v in values]
    if len(regs) == 1:
        return frame(bytes((unit, WRITE_SINGLE_REGISTER, address >> 8, address & 0xFF,
                            regs[0] >> 8, regs[0] & 0xFF)))
    n = len(regs)
    data = b"".join(bytes((v >> 8, v & 0xFF)) for v in regs)
    return frame(bytes((unit, WRITE_MULTIPLE_REGISTERS, address >> 8, address & 0xFF, n >> 8,
                        n & 0xFF, 2 * n)) + data)


def response_length(request: bytes) -> int:
    """Length in bytes of the normal reply to ``request`` (an exception reply is 5)."""
    function = request[1]
    if function in (READ_COILS, READ_DISCRETE_INPUTS):
        count = request[4] << 8 | request[5]
        return 5 + (count + 7) // 8
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        count = request[4] << 8 | request[5]
        return 5 + 2 * count
    return 8  # writes echo address and value/quantity


def decode_reply(request: bytes, reply: bytes) -> list[int]:
    """Items of a checked normal reply to a read request: bits (0/1) or registers."""
    function = request[1]
    count = request[4] << 8 | request[5]
    data = reply[3:-2]
    if function in (READ_COILS, READ_DISCRETE_INPUTS):
        return [(data[i // 8] >> (i % 8)) & 1 for i in range(count)]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS):
        return [data[2 * i] << 8 | data[2 * i + 1] for i in range(count)]
    return []


class ModbusError(DriverError):
    """A failed Modbus transaction; the message says which unit, function and address."""


class ModbusTimeout(ModbusError):
    """No (complete) reply within the timeout: unit absent, cable cut, wrong baud rate."""


class ModbusCrcError(ModbusError):
    """A reply with a bad CRC: noise on the line, a missing terminator, two masters."""


class ModbusFrameError(ModbusError):
    """A reply from another unit or function, or of the wrong length (a late reply)."""


class ModbusExceptionReply(ModbusError):
    """The unit answered with an exception: e.g. code 2 for an address it does not have."""

    def __init__(self, unit: int, function: int, code: int, what: str) -> None:
        self.unit, self.function, self.code = unit, function, code
        name = EXCEPTION_NAMES.get(code, "unknown exception")
        super().__init__(f"unit {unit}: exception {code} ({name}) to FC {function} {what}")


def describe(request: bytes) -> str:
    """``at address 16 (8 items)`` for a request, for fault messages."""
    address = request[2] << 8 | request[3]
    if request[1] in (WRITE_SINGLE_COIL, WRITE_SINGLE_REGISTER):
        return f"at address {address}"
    count = request[4] << 8 | request[5]
    return f"at address {address} ({count} items)"


# -- transport: one serial line ------------------------------------------------------------

@dataclass(frozen=True)
class SerialSettings:
    """What every driver sharing a port must agree on."""

    port: str
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1

    @property
    def char_s(self) -> float:
        """Time of one character on the wire (11 bits: start, 8 data, parity/stop, stop)."""
        return 11.0 / self.baudrate

    @property
    def t35_s(self) -> float:
        """Inter-frame silence: 3.5 characters, fixed 1.75 ms above 19200 baud."""
        return 0.00175 if self.baudrate > 19200 else 3.5 * self.char_s


@dataclass
class LineStats:
    """Counters of one serial line."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    crc_errors: int = 0
    frame_errors: int = 0
    exceptions: int = 0


class RtuMaster:
    """Request/reply transactions on one serial port; used by one thread at a time."""

    def __init__(self, settings: SerialSettings) -> None:
        self.settings = settings
        self.stats = LineStats()
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

    def transact(self, request: bytes, timeout: float, retries: int) -> bytes:
        """Send ``request``, return the checked normal reply. Retries timeouts and damaged
        replies; an exception reply raises ModbusExceptionReply at once."""
        last: ModbusError | None = None
        for attempt in range(retries + 1):
            if attempt:
                self.stats.retries += 1
            try:
                return self._once(request, timeout)
            except ModbusTimeout as exc:
                self.stats.timeouts += 1
                last = exc
            except ModbusCrcError as exc:
                self.stats.crc_errors += 1
                last = exc
            except ModbusFrameError as exc:
                self.stats.frame_errors += 1
                last = exc
            self._resync(timeout)
        assert last is not None
        raise type(last)(f"{last} (after {retries + 1} attempts)")

    def _once(self, request: bytes, timeout: float) -> bytes:
        unit, function = request[0], request[1]
        gap = self.settings.t35_s - (time.monotonic() - self._last_traffic)
        if gap > 0:
            time.sleep(gap)
        self._send(request)
        self.stats.requests += 1
        # ``timeout`` is the unit's time to answer: the wire time of our request and of its
        # full reply come on top (a 125-register reply is 255 bytes: 290 ms at 9600 baud)
        expected = response_length(request)
        deadline = (time.monotonic() + (len(request) + expected) * self.settings.char_s
                    + timeout)
        what = f"unit {unit}: FC {function} {describe(request)}"
        reply = self._read_exact(5, deadline, what)
        if reply[0] != unit or reply[1] & 0x7F != function:
            raise ModbusFrameError(f"{what}: reply from unit {reply[0]} FC {reply[1] & 0x7F}")
        if reply[1] & 0x80:
            if crc16(reply[:3]) != reply[3] | reply[4] << 8:
                raise ModbusCrcError(f"{what}: CRC error in exception reply")
            self.stats.exceptions += 1
            raise ModbusExceptionReply(unit, function, reply[2], describe(request))
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


# -- a shared port and its poll thread ---------------------------------------------------

class SerialLine:
    """One serial port shared by the drivers of its units, served by one poll thread."""

    #: seconds close() waits for a unit's last outputs (the safe state) to be written
    FLUSH_TIMEOUT_S: ClassVar[float] = 1.0
    #: seconds between rewrites of unchanged outputs (a unit may have restarted)
    OUTPUT_REFRESH_S: ClassVar[float] = 1.0
    #: seconds to wait for the poll thread to end on close
    JOIN_TIMEOUT_S: ClassVar[float] = 5.0

    _lines: ClassVar[dict[str, SerialLine]] = {}
    _registry_lock: ClassVar[threading.Lock] = threading.Lock()

    def __init__(self, settings: SerialSettings) -> None:
        self.settings = settings
        self.master = RtuMaster(settings)
        self.units: list[ModbusRtuDriver] = []
        self._units_lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = False
        self._thread: threading.Thread | None = None

    @classmethod
    def attach(cls, driver: ModbusRtuDriver) -> SerialLine:
        """The line of ``driver``'s port, opened and polling, with ``driver`` on it."""
        settings = driver.settings
        with cls._registry_lock:
            line = cls._lines.get(settings.port)
            if line is None:  # another name of the same device (/dev/serial/by-id/...)?
                real = os.path.realpath(settings.port)
                for other in cls._lines.values():
                    if os.path.realpath(other.settings.port) == real:
                        raise DriverError(f"{settings.port} is {real}, already opened as "
                                          f"{other.settings.port}: name a shared port the "
                                          "same way in every driver")
            if line is None:
                line = cls(settings)
                try:
                    line.master.open()
                except (OSError, serial.SerialException) as exc:
                    raise DriverError(f"{settings.port}: cannot open: {exc}") from exc
                cls._lines[settings.port] = line
            elif line.settings != settings:
                raise DriverError(f"{settings.port} is used by another driver with "
                                  f"{line.settings}; {driver.name} asks for {settings}")
            with line._units_lock:
                line.units.append(driver)
            if line._thread is None:
                line._thread = threading.Thread(target=line._run, daemon=True,
                                                name=f"modbus-rtu {settings.port}")
                line._thread.start()
        line.wake()
        return line

    def detach(self, driver: ModbusRtuDriver) -> None:
        """Take ``driver`` off the line; the last one out stops the thread, closes the port."""
        with SerialLine._registry_lock:
            with self._units_lock:
                if driver in self.units:
                    self.units.remove(driver)
                last = not self.units
            if not last:
                return
            SerialLine._lines.pop(self.settings.port, None)
            self._stopping = True
            self._wake.set()
            thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.JOIN_TIMEOUT_S)
        self.master.close()

    def wake(self) -> None:
        self._wake.set()

    def flush(self, driver: ModbusRtuDriver, timeout: float) -> bool:
        """Wait until the outputs ``driver`` holds now went out; False on timeout or fault."""
        target = driver._out_seq
        deadline = time.monotonic() + timeout
        while driver._written_seq < target:
            remaining = deadline - time.monotonic()
            thread = self._thread
            if remaining <= 0 or driver.io_faulted or thread is None or not thread.is_alive():
                return False
            driver._exchanged.clear()
            self.wake()
            driver._exchanged.wait(remaining)
        return True

    def _run(self) -> None:
        try:
            while True:
                self._wake.wait()
                self._wake.clear()
                if self._stopping:
                    return
                self._round()
        except BaseException as exc:  # a bug: every unit's scan re-raises it
            log.exception("modbus-rtu %s: poll thread failed", self.settings.port)
            with self._units_lock:
                units = list(self.units)
            for d in units:
                d.report_error(exc)
                d._exchanged.set()

    def _round(self) -> None:
        with self._units_lock:
            units = list(self.units)
        for d in units:
            if self._stopping:
                return
            probing = d.io_faulted
            if probing and not d._take_retry():
                d._exchanged.set()
                continue
            if not self.master.is_open:
                try:
                    self.master.open()
                    log.info("modbus-rtu %s: port open again", self.settings.port)
                except (OSError, serial.SerialException) as exc:
                    self._line_fault(units, f"{self.settings.port}: cannot open: {exc}")
                    return
            try:
                d._exchange(self.master, probing)
            except ModbusError as exc:
                d.mark_outputs_dirty()
                d.report_fault(str(exc))
            except (OSError, serial.SerialException) as exc:
                self.master.close()
                self._line_fault(units, f"{self.settings.port}: {exc}")
                return
            finally:
                d._exchanged.set()

    def _line_fault(self, units: list[ModbusRtuDriver], reason: str) -> None:
        for d in units:
            d.mark_outputs_dirty()
            d.report_fault(reason)
            d._exchanged.set()


# -- the driver ----------------------------------------------------------------------------

_POINT = re.compile(r"^(I|Q|IR|HR)([0-9]{1,5})$")
PARITIES = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD,
            "NONE": serial.PARITY_NONE, "EVEN": serial.PARITY_EVEN, "ODD": serial.PARITY_ODD}


@dataclass(frozen=True)
class ModbusConfig:
    """A modbus_rtu driver's configuration, checked on construction."""

    port: str
    unit: int
    baudrate: int = 19200
    parity: str = "N"
    stopbits: int = 1
    timeout_s: float = 0.1
    retries: int = 2

    @classmethod
    def from_mapping(cls, name: str, cfg: Mapping[str, Any]) -> ModbusConfig:
        def fail(key: str, expected: str) -> ConfigError:
            return ConfigError(f"driver {name} (modbus_rtu): {key}: expected {expected}, "
                               f"found {cfg.get(key)!r}")

        port = cfg.get("port")
        if not isinstance(port, str) or not port:
            raise fail("port", "a serial device such as /dev/ttyUSB0")
        unit = MODBUS_RTU_KEYS.value(cfg, "unit")
        if not isinstance(unit, int) or isinstance(unit, bool) or not 1 <= unit <= 247:
            raise fail("unit", "a slave address 1-247")
        baud = MODBUS_RTU_KEYS.value(cfg, "baudrate")
        if not isinstance(baud, int) or isinstance(baud, bool) or baud <= 0:
            raise fail("baudrate", "a baud rate such as 19200")
        parity = PARITIES.get(str(MODBUS_RTU_KEYS.value(cfg, "parity")).upper())
        if parity is None:
            raise fail("parity", "N, E or O")
        stopbits = MODBUS_RTU_KEYS.value(cfg, "stopbits")
        if stopbits not in (1, 2):
            raise fail("stopbits", "1 or 2")
        timeout = parse_duration(MODBUS_RTU_KEYS.value(cfg, "timeout"), f"driver {name} timeout")
        if timeout <= 0:
            raise fail("timeout", "a positive time such as 100ms")
        retries = MODBUS_RTU_KEYS.value(cfg, "retries")
        if not isinstance(retries, int) or isinstance(retries, bool) or not 0 <= retries <= 10:
            raise fail("retries", "0-10")
        return cls(port, unit, baud, parity, int(stopbits), timeout, retries)


@dataclass
class _Read:
    request: bytes
    address: int
    points: dict[int, str] = field(default_factory=dict)  # address -> point


@dataclass
class _Write:
    coils: bool
    address: int
    points: list[str]


class ModbusRtuDriver(PolledDriver):
    """One Modbus RTU slave unit on a (possibly shared) serial port."""

    type_name = "modbus_rtu"
    config_keys = MODBUS_RTU_KEYS
    ONE_DIRECTION_PER_POINT = True
    #: bit addresses this far apart are still read in one request (the gap is read too)
    BIT_GAP = 16

    def __init__(
        self,
        name: str,
        config: Mapping[str, Any] | None = None,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__(name, config, clock=clock)
        self.cfg = ModbusConfig.from_mapping(name, self.config)
        self.settings = SerialSettings(self.cfg.port, self.cfg.baudrate, self.cfg.parity,
                                       self.cfg.stopbits)
        self.stale_after_s = max(self.STALE_AFTER_S or 0.0,
                                 2 * (self.cfg.retries + 1) * self.cfg.timeout_s)
        self.line: SerialLine | None = None
        self._reads: list[_Read] = []
        self._writes: list[_Write] = []
        self._retry_flag = threading.Event()
        self._exchanged = threading.Event()
        self._last_write = 0.0
        self._last_outputs: dict[str, int] = {}
        self._written_seq = 0  # the output image sequence last written to the unit

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        m = _POINT.match(point)
        if m is None or int(m.group(2)) > 0xFFFF:
            raise PointError(f"{self.name}.{point}: a modbus_rtu point is I<n> (discrete "
                             "input), Q<n> (coil), IR<n> (input register) or HR<n> (holding "
                             "register), n from 0 to 65535")
        table = m.group(1)
        if direction is Direction.OUT and table in ("I", "IR"):
            what = "discrete input" if table == "I" else "input register"
            raise PointError(f"{self.name}.{point} is a {what}: read-only, it cannot be bound "
                             "as an output")
        return PointKind.BOOL if table in ("I", "Q") else PointKind.INT

    # -- poll plan ------------------------------------------------------------------------
    def _plan(self) -> None:
        by_fc: dict[int, dict[int, str]] = {}
        fc_of = {"I": READ_DISCRETE_INPUTS, "Q": READ_COILS, "IR": READ_INPUT_REGISTERS,
                 "HR": READ_HOLDING_REGISTERS}
        for point in self.inputs:
            m = _POINT.match(point)
            assert m is not None
            by_fc.setdefault(fc_of[m.group(1)], {})[int(m.group(2))] = point
        reads: list[_Read] = []
        for fc in sorted(by_fc):
            gap = self.BIT_GAP if fc <= READ_DISCRETE_INPUTS else 0
            for start, points in _runs(by_fc[fc], gap, MAX_ITEMS[fc]):
                count = max(points) - start + 1
                reads.append(_Read(read_request(self.cfg.unit, fc, start, count), start,
                                   points))
        writes: list[_Write] = []
        for table, fc in (("Q", WRITE_MULTIPLE_COILS), ("HR", WRITE_MULTIPLE_REGISTERS)):
            addrs = {}
            for point in self.outputs:
                m = _POINT.match(point)
                assert m is not None
                if m.group(1) == table:
                    addrs[int(m.group(2))] = point
            for start, points in _runs(addrs, 0, MAX_ITEMS[fc]):
                writes.append(_Write(table == "Q", start, [points[a] for a in sorted(points)]))
        self._reads, self._writes = reads, writes

    # -- I/O side (poll thread) -----------------------------------------------------------
    def _take_retry(self) -> bool:
        if self._retry_flag.is_set():
            self._retry_flag.clear()
            return True
        return False

    def _exchange(self, master: RtuMaster, probing: bool = False) -> None:
        """One exchange with this unit: changed outputs, then every input. ``probing``: the
        unit is faulted and this is its back-off attempt: one try per request, no retries,
        so a dead unit costs its neighbours one timeout per attempt."""
        cfg = self.cfg
        retries = 0 if probing else cfg.retries
        outputs = self.take_outputs()
        seq = self._out_taken
        now = time.monotonic()
        # unchanged outputs are written again now and then (the unit may have restarted),
        # and every round for a unit without inputs, where the write is the liveness check
        if outputs is None and self._writes and (
                not self._reads or now - self._last_write >= SerialLine.OUTPUT_REFRESH_S):
            outputs = self._last_outputs
        if outputs is not None and self._writes:
            try:
                for w in self._writes:
                    values = [outputs.get(p, 0) for p in w.points]
                    if w.coils:
                        request = write_coils_request(cfg.unit, w.address, values)
                    else:
                        request = write_registers_request(cfg.unit, w.address, values)
                    master.transact(request, cfg.timeout_s, retries)
            except BaseException:
                self.mark_outputs_dirty()
                raise
            self._last_outputs = outputs
            self._last_write = now
        self._written_seq = seq
        values_in: dict[str, int] = {}
        for r in self._reads:
            items = decode_reply(r.request, master.transact(r.request, cfg.timeout_s,
                                                            retries))
            for address, point in r.points.items():
                values_in[point] = items[address - r.address]
        self.publish_inputs(values_in)

    # -- PolledDriver hooks (scan thread) ---------------------------------------------------
    def _start(self) -> None:
        self._plan()
        self._retry_flag.clear()
        self.line = SerialLine.attach(self)

    def _stop(self) -> None:
        line, self.line = self.line, None
        if line is None:
            return
        if not self.io_faulted:
            line.flush(self, SerialLine.FLUSH_TIMEOUT_S)
        line.detach(self)

    def _wake(self) -> None:
        if self.line is not None:
            self.line.wake()

    def _retry(self) -> None:
        self._retry_flag.set()
        self._wake()


def _runs(addrs: Mapping[int, str], gap: int, limit: int) -> list[tuple[int, dict[int, str]]]:
    """Group sorted addresses into runs (start, {address: point}) for single requests."""
    runs: list[tuple[int, dict[int, str]]] = []
    for a in sorted(addrs):
        if runs:
            start, points = runs[-1]
            if a - max(points) - 1 <= gap and a - start + 1 <= limit:
                points[a] = addrs[a]
                continue
        runs.append((a, {a: addrs[a]}))
    return runs
