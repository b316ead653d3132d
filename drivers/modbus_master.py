"""A Modbus master's units on a shared link, whatever the transport: the poll plan of a unit
(``ModbusUnit``, the base of the modbus_rtu and modbus_tcp drivers), the link's poll thread
(``PollLink``: one serial port, or one TCP connection to a device or gateway) and the
registry of open links (``Links``).

Several drivers (one per *unit*) may share a link: they share one ``PollLink``, keyed by
the port path or ``host:port``, whose thread polls the units in turn, one round per scan
(``write()`` wakes it); each round first writes the outputs that changed, then reads the
bound inputs in as few requests as the addresses allow. A unit that fails is skipped by
later rounds until the scan asks for a retry (back-off in ``drivers.base``), so a dead unit
does not slow its neighbours down. A link that fails (the port gone, the connection
refused or reset) faults every unit on it; it is opened again by the next round that has
a unit to try, at that unit's back-off time.

The transport is a ``Master`` (``drivers.serial_line.RtuMaster``,
``drivers.modbus_tcp.TcpMaster``): ``transact(unit, pdu, timeout, retries)`` returns the
checked reply PDU; the PDU itself is ``drivers.modbus_frame``'s.

Points: ``I0``... discrete inputs (FC 2), ``Q0``... coils (written with FC 5/15, or read
with FC 1 when bound as an input), ``IR0``... input registers (FC 4), ``HR0``... holding
registers (written with FC 6/16, or read with FC 3). Numbers are protocol addresses, from 0;
a register is a 16-bit unsigned value, as the unit holds it.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

from drivers.base import DriverError, PolledDriver
from drivers.modbus_frame import (
    MAX_ITEMS,
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    WRITE_MULTIPLE_COILS,
    WRITE_MULTIPLE_REGISTERS,
    ModbusError,
    decode_items,
    read_pdu,
    write_coils_pdu,
    write_registers_pdu,
)

log = logging.getLogger(__name__)

_POINT = re.compile(r"^(I|Q|IR|HR)([0-9]{1,5})$")


@dataclass
class LinkStats:
    """Counters of one link."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    crc_errors: int = 0
    frame_errors: int = 0
    exceptions: int = 0
    #: (TCP) replies of an earlier, timed-out transaction, dropped
    late_replies: int = 0


class Master(Protocol):
    """A transport's request/reply transactions; used by one thread at a time."""

    stats: LinkStats

    @property
    def is_open(self) -> bool: ...

    def open(self) -> None:
        """Open the port, or connect; OSError (with the link's name) on failure."""

    def close(self) -> None: ...

    def transact(self, unit: int, pdu: bytes, timeout: float, retries: int) -> bytes:
        """Send ``pdu`` to ``unit``, return the checked normal reply PDU. ModbusError
        (timeout, damaged or exception reply) for this unit; OSError for the link."""


@dataclass
class _Read:
    pdu: bytes
    address: int
    points: dict[int, str] = field(default_factory=dict)  # address -> point


@dataclass
class _Write:
    coils: bool
    address: int
    points: list[str]


class ModbusUnit(PolledDriver):
    """One Modbus unit on a (possibly shared) link. A transport's driver sets, in its
    ``_init``: ``unit``, ``timeout_s``, ``retries``, ``links`` (the registry of its
    transport) and ``link_key`` (what units sharing a link have in common)."""

    ONE_DIRECTION_PER_POINT = True
    #: bit addresses this far apart are still read in one request (the gap is read too)
    BIT_GAP = 16

    unit: int
    timeout_s: float
    retries: int
    links: Links
    link_key: str

    def _init(self) -> None:
        super()._init()
        self.line: PollLink | None = None
        self._reads: list[_Read] = []
        self._writes: list[_Write] = []
        self._retry_flag = threading.Event()
        self._exchanged = threading.Event()
        self._last_write = 0.0
        self._last_outputs: dict[str, int] = {}
        self._written_seq = 0  # the output image sequence last written to the unit

    def _stale_after(self) -> None:
        """Inputs are stale after two full tries of an exchange."""
        self.stale_after_s = max(self.STALE_AFTER_S or 0.0,
                                 2 * (self.retries + 1) * self.timeout_s)

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
                reads.append(_Read(read_pdu(fc, start, count), start, points))
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

    def _exchange(self, master: Master, probing: bool = False) -> None:
        """One exchange with this unit: changed outputs, then every input. ``probing``: the
        unit is faulted and this is its back-off attempt: one try per request, no retries,
        so a dead unit costs its neighbours one timeout per attempt."""
        unit, timeout = self.unit, self.timeout_s
        retries = 0 if probing else self.retries
        outputs = self.take_outputs()
        seq = self._out_taken
        now = time.monotonic()
        # unchanged outputs are written again now and then (the unit may have restarted),
        # and every round for a unit without inputs, where the write is the liveness check
        if outputs is None and self._writes and (
                not self._reads or now - self._last_write >= PollLink.OUTPUT_REFRESH_S):
            outputs = self._last_outputs
        if outputs is not None and self._writes:
            try:
                for w in self._writes:
                    values = [outputs.get(p, 0) for p in w.points]
                    pdu = (write_coils_pdu(w.address, values) if w.coils
                           else write_registers_pdu(w.address, values))
                    master.transact(unit, pdu, timeout, retries)
            except BaseException:
                self.mark_outputs_dirty()
                raise
            self._last_outputs = outputs
            self._last_write = now
        self._written_seq = seq
        values_in: dict[str, int] = {}
        for r in self._reads:
            items = decode_items(r.pdu, master.transact(unit, r.pdu, timeout, retries))
            for address, point in r.points.items():
                values_in[point] = items[address - r.address]
        self.publish_inputs(values_in)

    # -- PolledDriver hooks (scan thread) ---------------------------------------------------
    def _start(self) -> None:
        self._plan()
        self._retry_flag.clear()
        self.line = self.links.attach(self)

    def _stop(self) -> None:
        line, self.line = self.line, None
        if line is None:
            return
        # even a faulted unit gets one more try: its relays may still be on
        if not line.flush(self, PollLink.FLUSH_TIMEOUT_S, probe=True):
            log.error("driver %s: unit %d did not confirm the safe state before the %s "
                      "closed: its outputs may still be on", self.name, self.unit, line.noun)
        self.links.detach(line, self)

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


class PollLink:
    """One link (a serial port, a TCP connection) shared by the drivers of its units,
    served by one poll thread named ``thread_name``."""

    #: seconds close() waits for a unit's last outputs (the safe state) to be written
    FLUSH_TIMEOUT_S: ClassVar[float] = 1.0
    #: seconds between rewrites of unchanged outputs (a unit may have restarted)
    OUTPUT_REFRESH_S: ClassVar[float] = 1.0
    #: seconds to wait for the poll thread to end on close
    JOIN_TIMEOUT_S: ClassVar[float] = 5.0

    def __init__(self, key: str, settings: Any, master: Master, thread_name: str,
                 verb: str = "open") -> None:
        self.key = key
        #: what every driver sharing the link must agree on
        self.settings = settings
        self.master = master
        self.thread_name = thread_name
        #: what opening it is called in messages: open (a port), connect (TCP)
        self.verb = verb
        #: what the link is called in messages: the port (RTU), the connection (TCP)
        self.noun = "connection" if verb == "connect" else "port"
        self.units: list[ModbusUnit] = []
        self._units_lock = threading.Lock()
        self._wake = threading.Event()
        self._stopping = False
        self._thread: threading.Thread | None = None

    def _add(self, driver: ModbusUnit) -> None:
        """Put ``driver`` on the link and start the poll thread if it is not running."""
        with self._units_lock:
            self.units.append(driver)
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, daemon=True,
                                            name=self.thread_name)
            self._thread.start()

    def _remove(self, driver: ModbusUnit) -> bool:
        """Take ``driver`` off the link; True if no unit is left."""
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
        """Wait for the poll thread (unless it is the caller), then close the link."""
        if thread is not None and thread is not threading.current_thread():
            thread.join(self.JOIN_TIMEOUT_S)
        self.master.close()

    def wake(self) -> None:
        self._wake.set()

    def open_error(self, exc: OSError) -> str:
        """Why the link could not be opened, as a fault reason."""
        return f"{self.key}: cannot {self.verb}: {exc}"

    def flush(self, driver: ModbusUnit, timeout: float, probe: bool = False) -> bool:
        """Wait until the outputs ``driver`` holds now went out; False on timeout or fault.
        ``probe``: a faulted unit is tried once more at once (the stop: the link may be
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
            log.exception("%s: poll thread failed", self.thread_name)
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
                except OSError as exc:
                    self._link_fault(units, self.open_error(exc))
                    return
                log.info("%s: %s again", self.thread_name,
                         "port open" if self.verb == "open" else "connected")
            try:
                d._exchange(self.master, probing)
            except ModbusError as exc:
                d.mark_outputs_dirty()
                d.report_fault(str(exc))
            except OSError as exc:
                self.master.close()
                self._link_fault(units, f"{self.key}: {exc}")
                return
            finally:
                d._exchanged.set()

    def _link_fault(self, units: list[ModbusUnit], reason: str) -> None:
        for d in units:
            d.mark_outputs_dirty()
            d.report_fault(reason)
            d._exchanged.set()


class Links:
    """The open links of one transport, by key: one ``PollLink`` per key, shared by the
    drivers of its units.

    A link lives from the first ``attach`` of its key to the last ``detach``: then its poll
    thread ends and the link is closed, so an instance is empty whenever none of its
    drivers is open. A transport says how a link is made (``_new_link``), checked against
    the other links (``_check_new``) and opened at once or by its first round
    (``OPEN_AT_ATTACH``)."""

    #: open the link in ``attach`` (the caller sees the failure as a DriverError); else
    #: the poll thread opens it (a TCP connect never runs in the scan thread)
    OPEN_AT_ATTACH: ClassVar[bool] = True

    def __init__(self) -> None:
        self._lines: dict[str, PollLink] = {}
        self._lock = threading.Lock()

    def _new_link(self, driver: ModbusUnit) -> PollLink:  # pragma: no cover - abstract
        raise NotImplementedError

    def _check_new(self, driver: ModbusUnit, others: list[PollLink]) -> None:
        """Raise DriverError if ``driver``'s new link clashes with the open ones."""

    def attach(self, driver: ModbusUnit) -> PollLink:
        """The link of ``driver``'s key, opened and polling, with ``driver`` on it.

        DriverError if it cannot be opened, clashes with another link, or is open with
        other settings."""
        key = driver.link_key
        with self._lock:
            line = self._lines.get(key)
            if line is None:
                self._check_new(driver, list(self._lines.values()))
                line = self._new_link(driver)
                if self.OPEN_AT_ATTACH:
                    try:
                        line.master.open()
                    except OSError as exc:
                        raise DriverError(line.open_error(exc)) from exc
                self._lines[key] = line
            elif line.settings != _settings(driver):
                raise DriverError(f"{key} is used by another driver with "
                                  f"{line.settings}; {driver.name} asks for "
                                  f"{_settings(driver)}")
            line._add(driver)
        line.wake()
        return line

    def detach(self, line: PollLink, driver: ModbusUnit) -> None:
        """Take ``driver`` off ``line``; the last one out stops its thread, closes it."""
        with self._lock:
            if not line._remove(driver):
                return
            self._lines.pop(line.key, None)
            thread = line._stop_polling()
        line._close(thread)

    def keys(self) -> list[str]:
        """The keys of the open links."""
        with self._lock:
            return list(self._lines)


def _settings(driver: ModbusUnit) -> Any:
    return getattr(driver, "settings", None)
