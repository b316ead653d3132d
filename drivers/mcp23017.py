"""MCP23017 16-bit I2C port expander through the kernel's i2c-dev (``smbus2``).

The chip is set up explicitly at open, whatever state it was left in:

* ``IOCON`` = 0x00: BANK=0 (A/B registers interleaved, the power-on layout), SEQOP=0
  (sequential addressing: every A/B register pair is one 2-byte transaction, and the
  set-up writes IODIR..DEFVAL in one block), no interrupts mirrored, push-pull INT pins.
  A chip left in BANK=1 by another program is first brought back to BANK=0 by writing
  0x00 to 0x05, which is IOCON in BANK=1 and GPINTENB (interrupts off, harmless) in BANK=0.
* ``OLAT`` before ``IODIR``, so an output comes up at its intended level without a glitch.
* ``IODIR`` from the bindings (1 = input; unbound pins stay inputs), ``IPOL`` and
  ``GPINTEN`` 0, ``DEFVAL`` a signature (unused with GPINTEN=0; it differs from the
  power-on value 0, so a reset is seen even when every pin is an input), ``GPPU`` from
  ``pull_up`` (default true) on the inputs.

Every scan reads GPIOA+GPIOB in one 2-byte block read and writes OLATA+OLATB (never GPIO,
never read-modify-write) when an output changed. Every ``CHECK_PERIOD_S`` the registers
IODIR..DEFVAL are read back; a difference means the chip lost power (or was reset) and it
is set up again.

Points ``A0``-``A7``, ``B0``-``B7``. Config::

    exp1: {type: mcp23017, bus: 1, address: 0x20, pull_up: true}
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from typing import Any

import smbus2

from drivers.base import Direction, Driver, DriverError, PointKind
from drivers.registry import MCP23017_KEYS, POINTS

log = logging.getLogger(__name__)

# register addresses with IOCON.BANK = 0 (the A register; B is the next address)
IODIRA = 0x00
IPOLA = 0x02
GPINTENA = 0x04
DEFVALA = 0x06
IOCON = 0x0A
GPPUA = 0x0C
GPIOA = 0x12
OLATA = 0x14
#: IOCON's address when IOCON.BANK = 1
IOCON_BANK1 = 0x05


class Mcp23017Driver(Driver):
    """One MCP23017; the I2C transfers (a few hundred µs at 400 kHz) run in the scan."""

    type_name = "mcp23017"
    config_keys = MCP23017_KEYS
    ONE_DIRECTION_PER_POINT = True
    #: seconds between read-backs of the set-up registers (power-loss detection)
    CHECK_PERIOD_S = 0.1
    #: IOCON value written at open: BANK=0, SEQOP=0 (sequential), everything else off
    IOCON_VALUE = 0x00
    #: DEFVALA/DEFVALB signature (power-on value is 0x00)
    SIGNATURE = (0xA5, 0x5A)

    def __init__(
        self,
        name: str,
        config: Mapping[str, Any] | None = None,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__(name, config, clock=clock)
        self.bus_number: int = self.params["bus"]
        self.address: int = self.params["address"]
        self.pull_up: bool = self.params["pull_up"]
        #: how many times the chip was found reset and set up again
        self.reinits = 0
        self._bus: Any = None
        self._iodir = [0xFF, 0xFF]
        self._gppu = [0, 0]
        self._olat: list[int] | None = None
        #: per input point: (its position in the image, port, bit), set by _open()
        self._in_bits: list[tuple[int, int, int]] = []
        self._next_check_ns = 0

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        return POINTS[self.type_name].check(self.name, point, direction)

    @staticmethod
    def _bit(point: str) -> tuple[int, int]:
        return (0 if point[0] == "A" else 1), int(point[1])

    def _where(self) -> str:
        return f"mcp23017 at 0x{self.address:02x} on /dev/i2c-{self.bus_number}"

    def _open(self) -> None:
        iodir, gppu = [0xFF, 0xFF], [0, 0]
        for point in self.outputs:
            port, bit = self._bit(point)
            iodir[port] &= ~(1 << bit) & 0xFF
        self._in_bits.clear()
        for point, i in self.inputs.index.items():
            port, bit = self._bit(point)
            self._in_bits.append((i, port, bit))
            if self.pull_up:
                gppu[port] |= 1 << bit
        self._iodir, self._gppu = iodir, gppu
        try:
            self._bus = smbus2.SMBus(self.bus_number)
            self._setup()
        except OSError as exc:
            self._close()
            raise DriverError(f"{self._where()}: {exc}") from exc
        except DriverError:
            self._close()
            raise

    def _expected(self) -> list[int]:
        return [*self._iodir, 0, 0, 0, 0, *self.SIGNATURE]

    def _setup(self) -> None:
        bus, addr = self._bus, self.address
        bus.write_byte_data(addr, IOCON_BANK1, 0x00)
        bus.write_byte_data(addr, IOCON, self.IOCON_VALUE)
        olat = self._olat_image()
        bus.write_i2c_block_data(addr, OLATA, olat)
        bus.write_i2c_block_data(addr, IODIRA, self._expected())
        bus.write_i2c_block_data(addr, GPPUA, self._gppu)
        self._olat = olat
        back = list(bus.read_i2c_block_data(addr, IODIRA, 8))
        if back != self._expected():
            raise DriverError(f"{self._where()}: registers do not keep their values "
                              f"(wrote {self._expected()}, read {back}): not an MCP23017?")
        self._next_check_ns = self.clock() + int(self.CHECK_PERIOD_S * 1e9)

    def _olat_image(self) -> list[int]:
        olat = [0, 0]
        if self.inhibited:  # a set-up again (power glitch, reconnect) must not energise
            return olat
        out = self.outputs
        for point, value in zip(out.index, out.vals, strict=True):  # no view
            if value:
                port, bit = self._bit(point)
                olat[port] |= 1 << bit
        return olat

    def _read(self) -> None:
        try:
            self._transfer_inputs()
        except OSError as exc:
            raise DriverError(f"{self._where()}: {exc}") from exc

    def _write(self) -> None:
        try:
            self._transfer_outputs()
        except OSError as exc:
            raise DriverError(f"{self._where()}: {exc}") from exc

    def _transfer_inputs(self) -> None:
        now = self.clock()
        if now >= self._next_check_ns:
            self._next_check_ns = now + int(self.CHECK_PERIOD_S * 1e9)
            back = list(self._bus.read_i2c_block_data(self.address, IODIRA, 8))
            if back != self._expected():
                log.warning("driver %s: %s lost its set-up (power loss or reset?): read %s, "
                            "expected %s; setting it up again", self.name, self._where(), back,
                            self._expected())
                self.reinits += 1
                self._setup()
        if not self._in_bits:
            return
        gpio = self._bus.read_i2c_block_data(self.address, GPIOA, 2)
        vals = self.inputs.vals
        for i, port, bit in self._in_bits:
            vals[i] = (gpio[port] >> bit) & 1 == 1

    def _transfer_outputs(self) -> None:
        if not self.outputs:
            return
        olat = self._olat_image()
        if olat != self._olat:
            self._bus.write_i2c_block_data(self.address, OLATA, olat)
            self._olat = olat

    def _safe_state(self) -> None:
        if self._bus is None:  # never opened, or lost: nothing to write to
            return
        self._olat = None  # write even if the cache says it is already off
        self._write()

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        self._olat = None
        if bus is not None:
            bus.close()
