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

The chip has no debounce: ``debounce`` filters the inputs in software (drivers/bank.py).

Points ``A0``-``A7``, ``B0``-``B7``. Config::

    exp1: {type: mcp23017, bus: 1, address: 0x20, pull_up: true, debounce: 10ms}
"""

from __future__ import annotations

import logging
from typing import Any

import smbus2

from drivers.bank import DigitalBank
from drivers.base import DriverError
from drivers.registry import MCP23017_KEYS

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


class Mcp23017Driver(DigitalBank):
    """One MCP23017; the I2C transfers (a few hundred µs at 400 kHz) run in the scan. Line
    n is A0..A7 for n = 0..7, B0..B7 for n = 8..15: the bank's word is GPIOA + 256 GPIOB."""

    type_name = "mcp23017"
    config_keys = MCP23017_KEYS
    SOFT_DEBOUNCE = True
    #: seconds between read-backs of the set-up registers (power-loss detection)
    CHECK_PERIOD_S = 0.1
    #: IOCON value written at open: BANK=0, SEQOP=0 (sequential), everything else off
    IOCON_VALUE = 0x00
    #: DEFVALA/DEFVALB signature (power-on value is 0x00)
    SIGNATURE = (0xA5, 0x5A)

    def _init(self) -> None:
        super()._init()
        self.bus_number: int = self.params["bus"]
        self.address: int = self.params["address"]
        self.pull_up: bool = self.params["pull_up"]
        #: how many times the chip was found reset and set up again
        self.reinits = 0
        self._bus: Any = None
        self._next_check_ns = 0

    def line(self, point: str) -> int:
        return (0 if point[0] == "A" else 8) + int(point[1])

    def where(self) -> str:
        return f"mcp23017 at 0x{self.address:02x} on /dev/i2c-{self.bus_number}"

    def _attach(self) -> int:
        self._bus = smbus2.SMBus(self.bus_number)
        return self._setup()

    def _expected(self) -> list[int]:
        """IODIRA..DEFVALB as the set-up writes them: 1 = input (unbound pins too), no
        inversion (IPOL 0: the binding inverts), no interrupts, the signature."""
        iodir = 0xFFFF & ~self.out_mask
        return [iodir & 0xFF, iodir >> 8, 0, 0, 0, 0, *self.SIGNATURE]

    def _setup(self) -> int:
        bus, addr = self._bus, self.address
        bus.write_byte_data(addr, IOCON_BANK1, 0x00)
        bus.write_byte_data(addr, IOCON, self.IOCON_VALUE)
        olat = self.setup_word()
        bus.write_i2c_block_data(addr, OLATA, [olat & 0xFF, olat >> 8])
        bus.write_i2c_block_data(addr, IODIRA, self._expected())
        gppu = self.in_mask if self.pull_up else 0
        bus.write_i2c_block_data(addr, GPPUA, [gppu & 0xFF, gppu >> 8])
        back = list(bus.read_i2c_block_data(addr, IODIRA, 8))
        if back != self._expected():
            raise DriverError(f"{self.where()}: registers do not keep their values "
                              f"(wrote {self._expected()}, read {back}): not an MCP23017?")
        self._next_check_ns = self.clock() + int(self.CHECK_PERIOD_S * 1e9)
        return olat

    def _read_word(self) -> int:
        now = self.clock()
        if now >= self._next_check_ns:
            self._next_check_ns = now + int(self.CHECK_PERIOD_S * 1e9)
            back = list(self._bus.read_i2c_block_data(self.address, IODIRA, 8))
            if back != self._expected():
                log.warning("driver %s: %s lost its set-up (power loss or reset?): read %s, "
                            "expected %s; setting it up again", self.name, self.where(), back,
                            self._expected())
                self.reinits += 1
                self._setup()
        if not self.in_mask:
            return 0
        gpio = self._bus.read_i2c_block_data(self.address, GPIOA, 2)
        return int(gpio[0]) | int(gpio[1]) << 8

    def _write_word(self, word: int, changed: int) -> None:
        self._bus.write_i2c_block_data(self.address, OLATA, [word & 0xFF, word >> 8])

    def _detach(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.close()
