"""PCF8574 8-bit quasi-bidirectional I2C port expander through i2c-dev (``smbus2``).

The chip has one latch and no registers: a 1 in the latch is a weak pull-up (the pin can
be read as an input, and pulled low from outside), a 0 drives the pin low. So the driver
keeps every input bit (and every unbound pin) at 1, and output bits at their value; one
byte written when an output changes, one byte read per scan.

A power loss resets the latch to 0xFF: an output the driver holds at 0 then reads back 1.
The scan's read sees that and writes the latch again.

Beware: the safe state is physical 0 on every output, i.e. the pin driven low. Boards that
switch a relay *on* with a low pin (most PCF8574 relay boards) need ``invert: true`` in
the binding and are energised in the safe state: see docs/drivers.md.

The chip has no debounce: ``debounce`` filters the inputs in software (drivers/bank.py).

Points ``P0``-``P7``. Config::

    exp2: {type: pcf8574, bus: 1, address: 0x38, debounce: 10ms}
"""

from __future__ import annotations

import logging
from typing import Any

import smbus2

from drivers.bank import DigitalBank
from drivers.registry import PCF8574_KEYS

log = logging.getLogger(__name__)


class Pcf8574Driver(DigitalBank):
    """One PCF8574 (or PCF8574A); one-byte transfers in the scan. Line n is Pn."""

    type_name = "pcf8574"
    config_keys = PCF8574_KEYS
    SOFT_DEBOUNCE = True

    def _init(self) -> None:
        super()._init()
        self.bus_number: int = self.params["bus"]
        self.address: int = self.params["address"]
        #: how many times the chip was found reset and its latch written again
        self.reinits = 0
        self._bus: Any = None

    def line(self, point: str) -> int:
        return int(point[1])

    def where(self) -> str:
        return f"pcf8574 at 0x{self.address:02x} on /dev/i2c-{self.bus_number}"

    def _latch(self, word: int) -> int:
        """The latch for the output word: inputs and unbound pins 1 (a weak pull-up)."""
        return (0xFF & ~self.out_mask) | word

    def _attach(self) -> int:
        self._bus = smbus2.SMBus(self.bus_number)
        word = self.setup_word()
        self._bus.write_byte(self.address, self._latch(word))
        return word

    def _read_word(self) -> int:
        pins = int(self._bus.read_byte(self.address))
        written = self.written
        lost = 0 if written is None else ~written & self.out_mask & pins
        if lost:  # driven low, yet reads high
            log.warning("driver %s: %s lost its latch (power loss?): outputs %s read "
                        "high; writing them again", self.name, self.where(),
                        [f"P{b}" for b in range(8) if lost >> b & 1])
            self.reinits += 1
            self._bus.write_byte(self.address, self._latch(self.setup_word()))
        return pins

    def _write_word(self, word: int, changed: int) -> None:
        self._bus.write_byte(self.address, self._latch(word))

    def _detach(self) -> None:
        bus, self._bus = self._bus, None
        if bus is not None:
            bus.close()
