"""Modbus RTU line layer: one serial port, its timing, and its sharing between units.

``RtuMaster`` does request/reply transactions on one port (t3.5 silences, deadlines from
the baud rate, retries, resynchronisation). ``SerialLine`` is one port shared by the
drivers of its units (one ``ModbusRtuDriver`` per unit), with one poll thread that serves
them in turn. ``SerialPorts`` owns the open lines of a process by port path: the first
driver of a port opens its line, the last one to leave closes it; ``shared_ports()`` is
the one used by default, empty whenever no Modbus driver is open.

pyserial only opens and configures the port (raw, exclusive); the I/O is ``os.write`` and
``select``/``os.read`` on its descriptor.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import termios
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import serial

from drivers.base import DriverError
from drivers.modbus_frame import (
    READ_INPUT_REGISTERS,
    ModbusCrcError,
    ModbusError,
    ModbusExceptionReply,
    ModbusFrameError,
    ModbusTimeout,
    crc16,
    describe,
    response_length,
)
from drivers.registry import MODBUS_RTU_KEYS

if TYPE_CHECKING:  # the driver imports this module
    from drivers.modbus_rtu import ModbusRtuDriver

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


class SerialLine:
    """One serial port shared by the drivers of its units, served by one poll thread."""

    #: seconds close() waits for a unit's last outputs (the safe state) to be written
    FLUSH_TIMEOUT_S: ClassVar[float] = 1.0
    #: seconds between rewrites of unchanged outputs (a unit may have restarted)
    OUTPUT_REFRESH_S: ClassVar[float] = 1.0
    #: seconds to wait for the poll thread to end on close
    JOIN_TIMEOUT_S: ClassVar[float] = 5.0

    def __init__(self, settings: SerialSettings) -> None:
        self.settings = settings
        self.master = RtuMaster(settings)
        self.units: list[ModbusRtuDriver] = []
        self._units_lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = False
        self._thread: threading.Thread | None = None

    def _add(self, driver: ModbusRtuDriver) -> None:
        """Put ``driver`` on the line and start the poll thread if it is not running."""
        with self._units_lock:
            self.units.append(driver)
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, daemon=True,
                                            name=f"modbus-rtu {self.settings.port}")
            self._thread.start()

    def _remove(self, driver: ModbusRtuDriver) -> bool:
        """Take ``driver`` off the line; True if no unit is left."""
        with self._units_lock:
            if driver in self.units:
                self.units.remove(driver)
            return not self.units

    def _stop_polling(self) -> threading.Thread | None:
        """Ask the poll thread to end; returns it, for ``_close`` to join."""
        self._stopping = True
        self._wake.set()
        thread, self._thread = self._thread, None
        return thread

    def _close(self, thread: threading.Thread | None) -> None:
        """Wait for the poll thread (unless it is the caller), then close the port."""
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.JOIN_TIMEOUT_S)
        self.master.close()

    def wake(self) -> None:
        self._wake.set()

    def flush(self, driver: ModbusRtuDriver, timeout: float, probe: bool = False) -> bool:
        """Wait until the outputs ``driver`` holds now went out; False on timeout or fault.
        ``probe``: a faulted unit is tried once more at once (the stop: the line may be
        back, and the outputs must go off)."""
        target = driver._out_seq
        deadline = time.monotonic() + timeout
        while driver._written_seq < target:
            remaining = deadline - time.monotonic()
            thread = self._thread
            if remaining <= 0 or thread is None or not thread.is_alive():
                return False
            if driver.io_faulted and not driver._retry_flag.is_set():
                if not probe:
                    return False  # faulted, and its one more try (if any) failed
                probe = False
                driver._retry_flag.set()  # taken by the next round, which writes
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


class SerialPorts:
    """The open serial lines, by port path: one ``SerialLine`` per port, shared by the
    drivers of its units.

    A line lives from the first ``attach`` of its port to the last ``detach``: then its
    poll thread ends and the port is closed, so an instance is empty whenever none of its
    drivers is open. Drivers use ``shared_ports()`` unless given their own (a test may
    pass a fresh one).
    """

    def __init__(self) -> None:
        self._lines: dict[str, SerialLine] = {}
        self._lock = threading.Lock()

    def attach(self, driver: ModbusRtuDriver) -> SerialLine:
        """The line of ``driver``'s port, opened and polling, with ``driver`` on it.

        DriverError if the port cannot be opened, is already open under another name
        (``/dev/serial/by-id/...``), or is open with other settings."""
        settings = driver.settings
        with self._lock:
            line = self._lines.get(settings.port)
            if line is None:  # another name of the same device (/dev/serial/by-id/...)?
                real = os.path.realpath(settings.port)
                for other in self._lines.values():
                    if os.path.realpath(other.settings.port) == real:
                        raise DriverError(f"{settings.port} is {real}, already opened as "
                                          f"{other.settings.port}: name a shared port the "
                                          "same way in every driver")
                line = SerialLine(settings)
                try:
                    line.master.open()
                except (OSError, serial.SerialException) as exc:
                    raise DriverError(f"{settings.port}: cannot open: {exc}") from exc
                self._lines[settings.port] = line
            elif line.settings != settings:
                raise DriverError(f"{settings.port} is used by another driver with "
                                  f"{line.settings}; {driver.name} asks for {settings}")
            line._add(driver)
        line.wake()
        return line

    def detach(self, line: SerialLine, driver: ModbusRtuDriver) -> None:
        """Take ``driver`` off ``line``; the last one out stops its thread, closes the port."""
        with self._lock:
            if not line._remove(driver):
                return
            self._lines.pop(line.settings.port, None)
            thread = line._stop_polling()
        line._close(thread)

    def ports(self) -> list[str]:
        """The paths of the open ports."""
        with self._lock:
            return list(self._lines)


_SHARED_PORTS = SerialPorts()


def shared_ports() -> SerialPorts:
    """The process's serial lines, shared by every Modbus driver not given its own
    ``SerialPorts``: two plants' drivers naming one port share its line (there is only
    one device). Empty whenever no such driver is open."""
    return _SHARED_PORTS
