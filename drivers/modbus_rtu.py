"""Modbus RTU master driver: one slave unit's points, polled off the scan.

Three layers, as pymodbus separates framer and transport: ``drivers.modbus_frame`` builds
and checks frames (pure), ``drivers.serial_line`` owns the port (timing, retries, one poll
thread per port shared by the units on it, ``SerialPorts``), and this module is the driver:
it plans the requests for its bound points and runs one exchange with its unit per round.

Why our own small master rather than pymodbus' client: a request through pymodbus' sync
client costs 2 ms or more on a pseudo-terminal (asyncio machinery on every call), and we
need exact control of the response timeout, of retries and of the inter-frame gap; the
part of Modbus RTU a PLC master needs (function codes 1, 2, 3, 4, 5, 6, 15, 16) is small
enough to carry.

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

import logging
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import serial

from drivers.base import PolledDriver
from drivers.modbus_frame import (
    MAX_ITEMS,
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    WRITE_MULTIPLE_COILS,
    WRITE_MULTIPLE_REGISTERS,
    decode_reply,
    read_request,
    write_coils_request,
    write_registers_request,
)
from drivers.registry import MODBUS_RTU_KEYS
from drivers.serial_line import RtuMaster, SerialLine, SerialPorts, SerialSettings, shared_ports

log = logging.getLogger(__name__)

_POINT = re.compile(r"^(I|Q|IR|HR)([0-9]{1,5})$")
#: the declared choices of ``parity`` (drivers.registry) as pyserial parities
PARITIES = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}


@dataclass(frozen=True)
class ModbusConfig:
    """A modbus_rtu driver's configuration, as checked by its declaration (MODBUS_RTU_KEYS,
    which holds the defaults and ranges)."""

    port: str
    unit: int
    baudrate: int
    parity: str  # a pyserial parity
    stopbits: int
    timeout_s: float
    retries: int

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> ModbusConfig:
        """From a driver's ``params`` (``ConfigKeys.validate``)."""
        return cls(params["port"], params["unit"], params["baudrate"],
                   PARITIES[params["parity"]], params["stopbits"], params["timeout"],
                   params["retries"])


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
        ports: SerialPorts | None = None,
    ) -> None:
        #: the open lines this driver's port is shared through (default: the process's)
        self.ports = shared_ports() if ports is None else ports
        super().__init__(name, config, clock=clock)

    def _init(self) -> None:
        super()._init()
        self.cfg = ModbusConfig.from_params(self.params)
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
        self.line = self.ports.attach(self)

    def _stop(self) -> None:
        line, self.line = self.line, None
        if line is None:
            return
        # even a faulted unit gets one more try: its relays may still be on
        if not line.flush(self, SerialLine.FLUSH_TIMEOUT_S, probe=True):
            log.error("driver %s: unit %d did not confirm the safe state before the port "
                      "closed: its outputs may still be on", self.name, self.cfg.unit)
        self.ports.detach(line, self)

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
