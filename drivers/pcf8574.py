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

Points ``P0``-``P7``. Config::

    exp2: {type: pcf8574, bus: 1, address: 0x38}
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from typing import Any

import smbus2

from drivers.base import Direction, Driver, DriverError, PointKind
from drivers.registry import PCF8574_KEYS, POINTS

log = logging.getLogger(__name__)


class Pcf8574Driver(Driver):
    """One PCF8574 (or PCF8574A); one-byte transfers in the scan."""

    type_name = "pcf8574"
    config_keys = PCF8574_KEYS
    ONE_DIRECTION_PER_POINT = True

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
        #: how many times the chip was found reset and its latch written again
        self.reinits = 0
        self._bus: Any = None
        self._latch: int | None = None
        self._out_mask = 0
        #: per input point: (its position in the image, its pin), set by _open()
        self._in_bits: list[tuple[int, int]] = []

    def _check_point(self, point: str, direction: Direction) -> PointKind:
        return POINTS[self.type_name].check(self.name, point, direction)

    def _where(self) -> str:
        return f"pcf8574 at 0x{self.address:02x} on /dev/i2c-{self.bus_number}"

    def _image(self) -> int:
        latch = 0xFF & ~self._out_mask  # inputs and unbound pins: 1 (weak pull-up)
        if self.inhibited:  # a latch rewrite (power glitch, reconnect) must not energise
            return latch
        out = self.outputs
        for point, value in zip(out.index, out.vals, strict=True):  # no view
            if value:
                latch |= 1 << int(point[1])
        return latch

    def _open(self) -> None:
        self._out_mask = 0
        for point in self.outputs:
            self._out_mask |= 1 << int(point[1])
        self._in_bits = [(i, int(p[1])) for p, i in self.inputs.index.items()]
        try:
            self._bus = smbus2.SMBus(self.bus_number)
            self._latch = None
            self._transfer_outputs()
        except OSError as exc:
            self._close()
            raise DriverError(f"{self._where()}: {exc}") from exc

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
        pins = self._bus.read_byte(self.address)
        if self._latch is not None:
            lost = ~self._latch & self._out_mask & pins  # driven low, yet reads high
            if lost:
                log.warning("driver %s: %s lost its latch (power loss?): outputs %s read "
                            "high; writing them again", self.name, self._where(),
                            [f"P{b}" for b in range(8) if lost >> b & 1])
                self.reinits += 1
                self._latch = None
                self._transfer_outputs()
        vals = self.inputs.vals
        for i, bit in self._in_bits:
            vals[i] = (pins >> bit) & 1 == 1

    def _transfer_outputs(self) -> None:
        latch = self._image()
        if latch != self._latch:
            self._bus.write_byte(self.address, latch)
            self._latch = latch

    def _safe_state(self) -> None:
        if self._bus is None:  # never opened, or lost: nothing to write to
            return
        self._latch = None
        self._write()

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        self._latch = None
        if bus is not None:
            bus.close()
