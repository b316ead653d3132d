"""Modbus RTU master driver: one slave unit's points, polled off the scan.

Three layers, as pymodbus separates framer and transport: ``drivers.modbus_frame`` builds
and checks PDUs and frames (pure), ``drivers.serial_line`` owns the port (timing, retries,
``SerialPorts``), ``drivers.modbus_master`` polls the units of one port in one thread and
plans each unit's requests for its bound points (``ModbusUnit``, shared with the
modbus_tcp driver); this module is the serial driver's configuration.

Why our own small master rather than pymodbus' client: a request through pymodbus' sync
client costs 2 ms or more on a pseudo-terminal (asyncio machinery on every call), and we
need exact control of the response timeout, of retries and of the inter-frame gap; the
part of Modbus RTU a PLC master needs (function codes 1, 2, 3, 4, 5, 6, 15, 16) is small
enough to carry.

Several drivers (one per slave *unit*) may share a port (``drivers.modbus_master``: one
poll round per scan, a dead unit skipped until its back-off).

Points: ``I0``... discrete inputs (FC 2), ``Q0``... coils (written with FC 5/15, or read
with FC 1 when bound as an input), ``IR0``... input registers (FC 4), ``HR0``... holding
registers (written with FC 6/16, or read with FC 3). Numbers are protocol addresses, from 0.
Config::

    mb: {type: modbus_rtu, port: /dev/ttyUSB0, baudrate: 115200, parity: E, unit: 1,
         timeout: 100ms, retries: 2}
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import serial

from drivers.modbus_master import ModbusUnit
from drivers.registry import MODBUS_RTU_KEYS
from drivers.serial_line import SerialPorts, SerialSettings, shared_ports

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


class ModbusRtuDriver(ModbusUnit):
    """One Modbus RTU slave unit on a (possibly shared) serial port."""

    type_name = "modbus_rtu"
    config_keys = MODBUS_RTU_KEYS

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
        self.unit, self.timeout_s, self.retries = (self.cfg.unit, self.cfg.timeout_s,
                                                   self.cfg.retries)
        self.links, self.link_key = self.ports, self.cfg.port
        self._stale_after()
