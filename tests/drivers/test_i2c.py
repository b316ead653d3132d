"""MCP23017 and PCF8574 drivers against the register-level emulator, plus an opt-in test on
a real /dev/i2c-* bus."""

from __future__ import annotations

import glob
import os

import pytest
import smbus2

from drivers.base import Direction, Health, PointError
from drivers.config import ConfigError
from drivers.mcp23017 import GPIOA, IODIRA, OLATA, Mcp23017Driver
from drivers.pcf8574 import Pcf8574Driver
from tests.drivers.drvkit import FakeClock
from tests.drivers.i2c_emulator import I2CWorld, Mcp23017Model, Pcf8574Model


@pytest.fixture
def world(monkeypatch: pytest.MonkeyPatch) -> I2CWorld:
    w = I2CWorld()
    monkeypatch.setattr(smbus2, "SMBus", w.smbus_class)
    return w


@pytest.fixture
def mcp(world: I2CWorld) -> Mcp23017Model:
    chip = world.bus(1).add(Mcp23017Model(0x20))
    assert isinstance(chip, Mcp23017Model)
    return chip


def make_mcp(clock: FakeClock, **cfg: object) -> Mcp23017Driver:
    d = Mcp23017Driver("exp1", {"bus": 1, "address": 32, **cfg}, clock=clock)
    for p in ("A0", "A1", "B7"):
        d.add_point(p, Direction.IN)
    for p in ("B0", "B1", "A7"):
        d.add_point(p, Direction.OUT)
    return d


def test_mcp_setup_from_bank1(world: I2CWorld, mcp: Mcp23017Model, clock: FakeClock) -> None:
    mcp.set_bank(1)  # left so by another program
    mcp.regs["IPOL"] = [0xFF, 0x00]  # and inputs inverted
    d = make_mcp(clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert mcp.bank == 0 and mcp.seqop == 0
    assert mcp.regs["IODIR"] == [0x7F, 0xFC]  # A7, B0, B1 outputs; the rest inputs
    assert mcp.regs["IPOL"] == [0, 0] and mcp.regs["GPINTEN"] == [0, 0]
    assert mcp.regs["GPPU"] == [0x03, 0x80]  # pull-ups on the bound inputs only
    assert mcp.regs["OLAT"] == [0, 0]
    assert all(mcp.pin(p) == 0 for p in ("A7", "B0", "B1"))
    d.close()
    assert world.open_handles == 0


@pytest.mark.parametrize("bank", [0, 1])
@pytest.mark.parametrize("others", [0x00, 0x20, 0x7E])  # SEQOP=1 (byte mode); every bit set
def test_mcp_iocon_set_explicitly_from_any_state(bank: int, others: int,
                                                 mcp: Mcp23017Model, clock: FakeClock) -> None:
    mcp.iocon = others & 0x7E
    mcp.set_bank(bank)
    mcp.regs["GPPU"] = [0xFF, 0xFF]
    mcp.regs["OLAT"] = [0xFF, 0xFF]  # a previous program left every latch on
    d = make_mcp(clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert mcp.iocon == Mcp23017Driver.IOCON_VALUE == 0x00  # BANK=0, SEQOP=0, MIRROR/ODR off
    assert mcp.regs["IODIR"] == [0x7F, 0xFC] and mcp.regs["GPPU"] == [0x03, 0x80]
    assert mcp.regs["OLAT"] == [0, 0] and all(mcp.pin(p) == 0 for p in ("A7", "B0", "B1"))
    mcp.drive("B7", 1)
    mcp.drive("A1", 0)
    d.read()
    assert d.inputs == {"A0": 1, "A1": 0, "B7": 1}
    d.close()


def test_mcp_outputs_never_glitch_on_at_open(world: I2CWorld, mcp: Mcp23017Model,
                                            clock: FakeClock) -> None:
    mcp.regs["OLAT"] = [0xFF, 0xFF]  # left on by someone; pins are inputs (power-on IODIR)
    d = make_mcp(clock)
    d.open()
    olat_at = iodir_at = None
    for i, t in enumerate(world.bus(1).log):
        if t.written[:1] == bytes([OLATA]) and olat_at is None:
            olat_at = i
        if t.written[:1] == bytes([IODIRA]) and len(t.written) > 1 and iodir_at is None:
            iodir_at = i
    assert olat_at is not None and iodir_at is not None and olat_at < iodir_at
    d.close()


def test_mcp_pull_up_off(mcp: Mcp23017Model, clock: FakeClock) -> None:
    d = make_mcp(clock, pull_up=False)
    d.open()
    assert mcp.regs["GPPU"] == [0, 0]
    d.close()


def test_mcp_scan_io_is_one_block_read_and_olat_writes(
    world: I2CWorld, mcp: Mcp23017Model, clock: FakeClock
) -> None:
    d = make_mcp(clock)
    d.open()
    log = world.bus(1).log
    log.clear()
    mcp.drive("A1", 0)  # A0 floats with its pull-up: 1
    mcp.drive("B7", 1)
    d.read()
    assert d.inputs == {"A0": 1, "A1": 0, "B7": 1}
    assert [(t.written, len(t.read)) for t in log] == [(bytes([GPIOA]), 2)]
    log.clear()
    d.outputs.update({"B1": True, "A7": 1})
    d.write()
    d.write()  # unchanged: no transfer
    assert [t.written for t in log] == [bytes([OLATA, 0x80, 0x02])]
    assert mcp.pin("B1") == 1 and mcp.pin("A7") == 1 and mcp.pin("B0") == 0
    d.safe_state()
    assert mcp.regs["OLAT"] == [0, 0]
    # never a write to GPIOA/GPIOB, never a read of OLAT (no read-modify-write)
    for t in world.bus(1).log:
        assert t.written[:1] not in (b"\x12", b"\x13") or not t.written[1:]
        assert not (t.written[:1] in (b"\x14", b"\x15") and t.read)
    d.close()


def test_mcp_power_blip_detected_and_set_up_again(mcp: Mcp23017Model, clock: FakeClock) -> None:
    d = make_mcp(clock)
    d.open()
    d.outputs["B0"] = 1
    d.write()
    mcp.power_off()
    mcp.power_on()  # between two scans: every register back to its power-on value
    assert mcp.pin("B0") == 0
    d.read()
    assert d.reinits == 0  # not yet time to check
    clock.advance(d.CHECK_PERIOD_S)
    d.read()
    assert d.reinits == 1 and d.health is Health.OK
    assert mcp.regs["IODIR"] == [0x7F, 0xFC] and mcp.pin("B0") == 1


def test_mcp_reset_seen_with_inputs_only(world: I2CWorld, clock: FakeClock) -> None:
    chip = world.bus(1).add(Mcp23017Model(0x21))
    assert isinstance(chip, Mcp23017Model)
    d = Mcp23017Driver("exp2", {"bus": 1, "address": 0x21, "pull_up": False}, clock=clock)
    d.add_point("A0", Direction.IN)  # IODIR is 0xFF as after power-on: the signature tells
    d.open()
    chip.power_off()
    chip.power_on()
    clock.advance(d.CHECK_PERIOD_S)
    d.read()
    assert d.reinits == 1
    d.close()


def test_mcp_absent_then_back(mcp: Mcp23017Model, clock: FakeClock) -> None:
    d = make_mcp(clock, on_fault="hold")
    d.open()
    mcp.drive("A0", 0)
    d.read()
    mcp.power_off()
    d.read()
    assert d.health is Health.FAULT and "Remote I/O error" in (d.fault_reason or "")
    assert "0x20" in (d.fault_reason or "")
    assert d.inputs["A0"] == 0  # hold: last good value
    mcp.power_on()
    clock.advance(d.RECONNECT_MIN_S / 2)
    d.read()
    assert d.health is Health.FAULT
    clock.advance(d.RECONNECT_MIN_S / 2)
    d.read()
    assert d.health is Health.OK
    assert mcp.regs["IODIR"] == [0x7F, 0xFC]
    d.close()


def test_mcp_missing_bus(world: I2CWorld, clock: FakeClock) -> None:
    d = Mcp23017Driver("exp1", {"bus": 7, "address": 0x20}, clock=clock)
    d.add_point("A0", Direction.IN)
    d.open()
    assert d.health is Health.FAULT and "/dev/i2c-7" in (d.fault_reason or "")
    d.close()


@pytest.mark.parametrize("point", ["C0", "A8", "a0", "A", "B10", "P0"])
def test_mcp_bad_points(point: str) -> None:
    d = Mcp23017Driver("exp1", {"bus": 1, "address": 0x20})
    with pytest.raises(PointError):
        d.add_point(point, Direction.IN)


@pytest.mark.parametrize("cfg", [{"bus": 1, "address": 300}, {"bus": "one", "address": 0x20},
                                 {"bus": 1}, {"bus": 1, "address": 0x20, "pull_up": "yes"},
                                 {"bus": 1, "address": 0x20, "speed": 4}])
def test_mcp_bad_config(cfg: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        Mcp23017Driver("exp1", cfg)


def test_address_as_string_accepted() -> None:
    assert Mcp23017Driver("exp1", {"bus": 1, "address": "0x27"}).address == 0x27


# -- PCF8574 ----------------------------------------------------------------------------
@pytest.fixture
def pcf(world: I2CWorld) -> Pcf8574Model:
    chip = world.bus(1).add(Pcf8574Model(0x38))
    assert isinstance(chip, Pcf8574Model)
    return chip


def make_pcf(clock: FakeClock) -> Pcf8574Driver:
    d = Pcf8574Driver("exp3", {"bus": 1, "address": 0x38}, clock=clock)
    d.add_point("P0", Direction.IN)
    d.add_point("P1", Direction.IN)
    d.add_point("P4", Direction.OUT)
    d.add_point("P5", Direction.OUT)
    return d


def test_pcf_quasi_bidirectional(world: I2CWorld, pcf: Pcf8574Model, clock: FakeClock) -> None:
    d = make_pcf(clock)
    d.open()
    assert pcf.history == [0xCF]  # inputs and unbound pins 1, outputs 0: one byte, no glitch
    pcf.drive(1, 0)
    d.read()
    assert d.inputs == {"P0": 1, "P1": 0}
    d.outputs["P5"] = True
    d.write()
    d.write()
    assert pcf.history == [0xCF, 0xEF]
    assert pcf.pin(5) == 1 and pcf.pin(4) == 0
    d.safe_state()
    assert pcf.latch == 0xCF
    d.close()
    assert world.open_handles == 0


def test_pcf_power_blip_rewrites_latch(pcf: Pcf8574Model, clock: FakeClock) -> None:
    d = make_pcf(clock)
    d.open()
    pcf.power_off()
    pcf.power_on()  # latch back to 0xFF: P4 and P5 float high
    d.read()
    assert d.reinits == 1 and pcf.latch == 0xCF
    d.close()


def test_pcf_absent(pcf: Pcf8574Model, clock: FakeClock) -> None:
    pcf.power_off()
    d = make_pcf(clock)
    d.open()
    assert d.health is Health.FAULT and "0x38" in (d.fault_reason or "")
    d.close()


@pytest.mark.parametrize("point", ["P8", "A0", "p0", "P"])
def test_pcf_bad_points(point: str) -> None:
    with pytest.raises(PointError):
        Pcf8574Driver("exp3", {"bus": 1, "address": 0x38}).add_point(point, Direction.OUT)


# -- opt-in: a real expander ---------------------------------------------------------------
REAL = os.environ.get("SOFTPLC_TEST_I2C", "")


@pytest.mark.skipif(not glob.glob("/dev/i2c-*"), reason="no /dev/i2c-* on this machine")
@pytest.mark.skipif(not REAL, reason="set SOFTPLC_TEST_I2C=mcp23017:BUS:ADDR or "
                    "pcf8574:BUS:ADDR to read a real expander (inputs only, nothing driven)")
def test_real_expander_inputs() -> None:
    kind, bus, addr = REAL.split(":")
    cls = Mcp23017Driver if kind == "mcp23017" else Pcf8574Driver
    d = cls("real", {"bus": int(bus), "address": int(addr, 0)})
    for p in (["A0", "B0"] if kind == "mcp23017" else ["P0"]):
        d.add_point(p, Direction.IN)
    d.open()
    try:
        assert d.health is Health.OK, d.fault_reason
        d.read()
        assert d.health is Health.OK, d.fault_reason
    finally:
        d.close()
