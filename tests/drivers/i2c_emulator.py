"""I2C buses with MCP23017 and PCF8574 chips modelled at the register/latch level.

``FakeSMBus`` has the methods of ``smbus2.SMBus`` that drivers use and is installed over
it by the tests (monkeypatch); production code never sees this module. Each smbus call is
turned into the I2C transaction the kernel would put on the wire (a write of the command
byte and data, and/or a read of N bytes), which the chip model answers:

* MCP23017 (datasheet DS20001952): 11 register kinds x 2 ports, laid out by IOCON.BANK
  (BANK=0 interleaved A/B at 0x00-0x15, BANK=1 port A at 0x00-0x0A and B at 0x10-0x1A);
  the address pointer advances per IOCON.SEQOP (sequential: +1 with roll-over; byte mode:
  toggles A/B with BANK=0, stays with BANK=1); GPIO reads the pins (IPOL applied), a write
  to GPIO writes OLAT; inputs follow what drives them from outside, else GPPU pull-up, else
  ``floating_level``; power-on reset values (IODIR=0xFF, everything else 0).
* PCF8574: one quasi-bidirectional latch (power-on 0xFF); a pin reads low if the latch
  drives it low or something outside pulls it low.

A chip that is powered off does not acknowledge (EREMOTEIO), a missing bus fails to open
(ENOENT), and ``fail`` makes every transfer on a bus raise.
"""

from __future__ import annotations

import errno
from dataclasses import dataclass, field
from typing import Any

REG_KINDS = ["IODIR", "IPOL", "GPINTEN", "DEFVAL", "INTCON", "IOCON", "GPPU", "INTF",
             "INTCAP", "GPIO", "OLAT"]
POR = {"IODIR": 0xFF}


@dataclass
class Transfer:
    """One I2C transaction: bytes written (command byte first), then bytes read."""

    address: int
    written: bytes
    read: bytes = b""


class Chip:
    """Base of the chip models: a 7-bit address and power."""

    def __init__(self, address: int) -> None:
        self.address = address
        self.powered = True

    def transfer(self, written: bytes, read_len: int) -> bytes:  # pragma: no cover
        raise NotImplementedError


class Mcp23017Model(Chip):
    """The MCP23017 register file and its 16 pins."""

    def __init__(self, address: int = 0x20) -> None:
        super().__init__(address)
        #: level driven on each pin from outside ("A0".."B7"), None: nothing connected
        self.external: dict[str, int | None] = {}
        #: level of a pin with nothing driving it and no pull-up
        self.floating_level = 0
        self.power_on_reset()

    # -- the outside world ------------------------------------------------------------
    def power_on_reset(self) -> None:
        self.regs = {k: [POR.get(k, 0), POR.get(k, 0)] for k in REG_KINDS if k != "IOCON"}
        self.iocon = 0x00
        self.pointer = 0

    def power_off(self) -> None:
        self.powered = False

    def power_on(self) -> None:
        self.powered = True
        self.power_on_reset()

    def drive(self, pin: str, level: int | None) -> None:
        self.external[pin] = level

    def pin(self, pin: str) -> int:
        """The physical level of a pin ("A0".."B7")."""
        port, bit = (0 if pin[0] == "A" else 1), int(pin[1])
        if not self.regs["IODIR"][port] >> bit & 1:  # output
            return self.regs["OLAT"][port] >> bit & 1
        ext = self.external.get(pin)
        if ext is not None:
            return ext
        if self.regs["GPPU"][port] >> bit & 1:
            return 1
        return self.floating_level

    def set_bank(self, bank: int) -> None:
        """Put the chip in BANK mode 0 or 1 (as another program might have left it)."""
        self.iocon = (self.iocon & 0x7F) | (0x80 if bank else 0)

    # -- register map -----------------------------------------------------------------
    @property
    def bank(self) -> int:
        return self.iocon >> 7 & 1

    @property
    def seqop(self) -> int:
        return self.iocon >> 5 & 1

    def decode(self, addr: int) -> tuple[str, int] | None:
        """Register kind and port at ``addr`` in the current BANK mode (None: unused)."""
        if self.bank == 0:
            if addr > 0x15:
                return None
            return REG_KINDS[addr // 2], addr % 2
        port, idx = divmod(addr, 0x10)
        if port > 1 or idx > 0x0A:
            return None
        return REG_KINDS[idx], port

    def _advance(self) -> None:
        if self.seqop:  # byte mode
            if self.bank == 0:
                self.pointer ^= 1
            return
        if self.bank == 0:
            self.pointer = 0 if self.pointer >= 0x15 else self.pointer + 1
        elif self.pointer == 0x0A:
            self.pointer = 0x10
        else:
            self.pointer = 0 if self.pointer >= 0x1A else self.pointer + 1

    def _read_reg(self, addr: int) -> int:
        where = self.decode(addr)
        if where is None:
            return 0
        kind, port = where
        if kind == "IOCON":
            return self.iocon & 0xFE
        if kind == "GPIO":
            value = 0
            for bit in range(8):
                value |= self.pin(f"{'AB'[port]}{bit}") << bit
            return value ^ self.regs["IPOL"][port]
        return self.regs[kind][port]

    def _write_reg(self, addr: int, value: int) -> None:
        where = self.decode(addr)
        if where is None:
            return
        kind, port = where
        if kind == "IOCON":
            self.iocon = value & 0xFE
        elif kind == "GPIO":
            self.regs["OLAT"][port] = value
        elif kind not in ("INTF", "INTCAP"):
            self.regs[kind][port] = value

    def transfer(self, written: bytes, read_len: int) -> bytes:
        if written:
            self.pointer = written[0]
            for value in written[1:]:
                self._write_reg(self.pointer, value)
                self._advance()
        out = bytearray()
        for _ in range(read_len):
            out.append(self._read_reg(self.pointer))
            self._advance()
        return bytes(out)


class Pcf8574Model(Chip):
    """The PCF8574 latch and its 8 pins."""

    def __init__(self, address: int = 0x38) -> None:
        super().__init__(address)
        self.latch = 0xFF
        #: every byte written to the latch, in order (to see glitches)
        self.history: list[int] = []
        self.external: dict[int, int | None] = {}

    def power_off(self) -> None:
        self.powered = False

    def power_on(self) -> None:
        self.powered = True
        self.latch = 0xFF

    def drive(self, pin: int, level: int | None) -> None:
        self.external[pin] = level

    def pin(self, pin: int) -> int:
        if not self.latch >> pin & 1:
            return 0  # strong pull-down wins
        ext = self.external.get(pin)
        return 1 if ext is None else ext

    def transfer(self, written: bytes, read_len: int) -> bytes:
        for value in written:  # no command byte: every byte goes to the latch
            self.latch = value
            self.history.append(value)
        return bytes(sum(self.pin(p) << p for p in range(8)) for _ in range(read_len))


@dataclass
class I2CBus:
    """One /dev/i2c-N with its chips."""

    number: int
    chips: dict[int, Chip] = field(default_factory=dict)
    log: list[Transfer] = field(default_factory=list)
    #: raise this on every transfer (a shorted or disconnected bus)
    fail: OSError | None = None

    def add(self, chip: Chip) -> Chip:
        self.chips[chip.address] = chip
        return chip

    def transfer(self, address: int, written: bytes, read_len: int) -> bytes:
        if self.fail is not None:
            raise self.fail
        chip = self.chips.get(address)
        if chip is None or not chip.powered:
            raise OSError(errno.EREMOTEIO, "Remote I/O error")
        data = chip.transfer(written, read_len)
        self.log.append(Transfer(address, bytes(written), data))
        return data


class I2CWorld:
    """Every fake bus; ``smbus_class`` stands in for ``smbus2.SMBus``."""

    def __init__(self) -> None:
        self.buses: dict[int, I2CBus] = {}
        self.open_handles = 0

    def bus(self, number: int) -> I2CBus:
        return self.buses.setdefault(number, I2CBus(number))

    @property
    def smbus_class(self) -> type:
        world = self

        class FakeSMBus:
            """smbus2.SMBus over the fake buses."""

            def __init__(self, bus: int | None = None, force: bool = False) -> None:
                self._bus: I2CBus | None = None
                if bus is not None:
                    self.open(bus)

            def open(self, bus: int) -> None:
                if bus not in world.buses:
                    raise FileNotFoundError(errno.ENOENT, "No such file or directory",
                                            f"/dev/i2c-{bus}")
                self._bus = world.buses[bus]
                world.open_handles += 1

            def close(self) -> None:
                if self._bus is not None:
                    self._bus = None
                    world.open_handles -= 1

            def __enter__(self) -> Any:
                return self

            def __exit__(self, *exc: object) -> None:
                self.close()

            def _t(self, addr: int, written: bytes, read_len: int = 0) -> bytes:
                if self._bus is None:
                    raise OSError(errno.EBADF, "Bad file descriptor")
                return self._bus.transfer(addr, written, read_len)

            def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
                return self._t(i2c_addr, b"", 1)[0]

            def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
                self._t(i2c_addr, bytes([value]))

            def read_byte_data(self, i2c_addr: int, register: int,
                               force: bool | None = None) -> int:
                return self._t(i2c_addr, bytes([register]), 1)[0]

            def write_byte_data(self, i2c_addr: int, register: int, value: int,
                                force: bool | None = None) -> None:
                self._t(i2c_addr, bytes([register, value]))

            def read_i2c_block_data(self, i2c_addr: int, register: int, length: int,
                                    force: bool | None = None) -> list[int]:
                if length > 32:
                    raise ValueError("Desired block length over 32 bytes")
                return list(self._t(i2c_addr, bytes([register]), length))

            def write_i2c_block_data(self, i2c_addr: int, register: int, data: list[int],
                                     force: bool | None = None) -> None:
                if len(data) > 32:
                    raise ValueError("Data length cannot exceed 32 bytes")
                self._t(i2c_addr, bytes([register, *data]))

        return FakeSMBus
