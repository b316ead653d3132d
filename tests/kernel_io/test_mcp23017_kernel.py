"""The mcp23017 driver through the kernel's i2c-dev on an i2c-stub chip: 256 registers of
plain memory, zeroed for each test, read and written with the SMBus and I2C block transfers
the driver uses on a board. The stub has the registers but not the chip's logic (no BANK
switch, no pins): what is checked is what the driver puts in them and reads from them, and
its set-up again after a power loss (every register back to 0, as the stub's memory is
made to be). The PCF8574 stays on the Python model: the stub cannot show its one latch."""

from __future__ import annotations

import pytest

from drivers.base import Direction, Health
from drivers.mcp23017 import (
    DEFVALA,
    GPINTENA,
    GPIOA,
    GPPUA,
    IOCON,
    IOCON_BANK1,
    IODIRA,
    IPOLA,
    OLATA,
    Mcp23017Driver,
)
from tests.drivers.drvkit import FakeClock
from tests.kernel_io.kio import StubChip

pytestmark = pytest.mark.kernel_io


def make(stub: StubChip, clock: FakeClock, **cfg: object) -> Mcp23017Driver:
    d = Mcp23017Driver("exp1", {"bus": stub.bus_number, "address": stub.address, **cfg},
                       clock=clock)
    for p in ("A0", "A1", "B7"):
        d.add_point(p, Direction.IN)
    for p in ("B0", "B1", "A7"):
        d.add_point(p, Direction.OUT)
    return d


def regs(stub: StubChip, first: int) -> tuple[int, int]:
    return stub.peek(first), stub.peek(first + 1)


def test_set_up_from_whatever_was_left(stub: StubChip, clock: FakeClock) -> None:
    for reg, value in ((IOCON_BANK1, 0x80), (IOCON, 0x7E), (IPOLA, 0xFF), (IPOLA + 1, 0xFF),
                       (OLATA, 0xFF), (OLATA + 1, 0xFF), (GPPUA, 0xFF), (GPINTENA, 0xFF)):
        stub.poke(reg, value)  # another program's set-up
    d = make(stub, clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert stub.peek(IOCON_BANK1) == 0 and stub.peek(IOCON) == 0  # BANK=0, SEQOP=0
    assert regs(stub, IODIRA) == (0x7F, 0xFC)  # A7, B0, B1 outputs; the rest inputs
    assert regs(stub, IPOLA) == (0, 0) and regs(stub, GPINTENA) == (0, 0)
    assert regs(stub, DEFVALA) == Mcp23017Driver.SIGNATURE
    assert regs(stub, GPPUA) == (0x03, 0x80)  # pull-ups on the bound inputs only
    assert regs(stub, OLATA) == (0, 0)  # every output off
    d.close()


def test_outputs_go_to_olat_and_inputs_come_from_gpio(stub: StubChip,
                                                     clock: FakeClock) -> None:
    d = make(stub, clock)
    d.open()
    d.outputs.update({"B1": True, "A7": 1})
    d.write()
    assert regs(stub, OLATA) == (0x80, 0x02)
    assert regs(stub, GPIOA) == (0, 0)  # never a write to GPIO
    stub.poke(GPIOA, 0x01)
    stub.poke(GPIOA + 1, 0x80)
    d.read()
    assert d.inputs == {"A0": 1, "A1": 0, "B7": 1}
    d.safe_state()
    assert regs(stub, OLATA) == (0, 0)
    d.close()


def test_a_power_loss_is_seen_and_the_chip_set_up_again(stub: StubChip,
                                                       clock: FakeClock) -> None:
    d = make(stub, clock)
    d.open()
    d.outputs["B0"] = 1
    d.write()
    assert regs(stub, OLATA) == (0, 0x01)
    stub.zero()  # the power went and came back between two scans
    d.read()
    assert d.reinits == 0  # not yet time to check
    clock.advance(d.CHECK_PERIOD_S)
    d.read()
    assert d.reinits == 1 and d.health is Health.OK
    assert regs(stub, IODIRA) == (0x7F, 0xFC)
    assert regs(stub, DEFVALA) == Mcp23017Driver.SIGNATURE
    assert regs(stub, OLATA) == (0, 0x01)  # its outputs as the image holds them
    d.close()


def test_an_absent_address_is_a_fault_naming_it(stub: StubChip, clock: FakeClock) -> None:
    d = Mcp23017Driver("exp9", {"bus": stub.bus_number, "address": 0x27}, clock=clock)
    d.add_point("A0", Direction.IN)
    d.open()
    assert d.health is Health.FAULT
    assert f"mcp23017 at 0x27 on /dev/i2c-{stub.bus_number}" in (d.fault_reason or "")
    d.close()
