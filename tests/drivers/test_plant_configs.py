"""The example plants of configs/ (MCP23017, CANopen node, Modbus module) load, and run the
drawer tester end to end on their driver's emulator or peer: start pressed -> valve open."""

from __future__ import annotations

import re
import shutil
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import pytest
import smbus2

from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from tests.drivers.canopen_slave import Cia401Slave
from tests.drivers.drvkit import wait_until
from tests.drivers.i2c_emulator import I2CWorld, Mcp23017Model
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

def layout(tmp_path: Path, name: str) -> str:
    """configs/<name>/plant.yaml beside a drawer_tester/ directory, in tmp_path."""
    chart = tmp_path / "drawer_tester" / "drawer_tester.yaml"
    chart.parent.mkdir()
    shutil.copy(CONFIGS / "drawer_tester" / "drawer_tester.yaml", chart)
    (tmp_path / name).mkdir()
    shutil.copy(CONFIGS / name / "plant.yaml", tmp_path / name / "plant.yaml")
    return str(tmp_path / name / "plant.yaml")


def run_until(plant: Plant, cond: Callable[[], bool], settle: bool) -> bool:
    """Cycle the plant (real time for bus drivers) until ``cond``."""
    now = 0
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        plant.cycle(now)
        now += plant.cycle_ns
        if cond():
            return True
        if settle:
            time.sleep(plant.cycle_ns / 1e9)
    return False


def start_test(plant: Plant, set_stop_closed: Callable[[], None],
               press_start: Callable[[], None], valve_open: Callable[[], bool],
               settle: bool) -> None:
    set_stop_closed()
    for _ in range(5):
        plant.cycle(0)
        if settle:
            time.sleep(plant.cycle_ns / 1e9)
    assert not valve_open()
    press_start()
    assert run_until(plant, valve_open, settle)
    assert plant.faulted() is None


def test_pi_mcp23017(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    world = I2CWorld()
    chip = Mcp23017Model(0x20)
    world.bus(1).add(chip)
    monkeypatch.setattr(smbus2, "SMBus", world.smbus_class)
    pdef = load_plant(layout(tmp_path, "pi_mcp23017"))
    assert pdef.drivers["exp1"].config["address"] == 0x20
    plant = Plant(pdef)
    plant.open()
    try:
        assert plant.drivers["exp1"].ok, plant.drivers["exp1"].fault_reason
        assert chip.regs["IODIR"] == [0xFF, 0xF0] and chip.regs["GPPU"] == [0, 0]
        start_test(plant, lambda: chip.drive("A0", 1), lambda: chip.drive("A1", 1),
                   lambda: chip.pin("B0") == 1 and chip.pin("B3") == 1, settle=False)
    finally:
        plant.close()
    assert chip.regs["OLAT"] == [0, 0]


def test_canopen_node(tmp_path: Path) -> None:
    pdef = load_plant(layout(tmp_path, "canopen_node"))
    channel = f"softplc-{uuid.uuid4().hex[:8]}"
    pdef.drivers["rio"].config.update(interface="virtual", channel=channel)
    pdef.drivers["rio"].config.pop("bitrate")
    with Cia401Slave(5, channel=channel) as slave:
        plant = Plant(pdef)
        plant.open()
        try:
            assert plant.drivers["rio"].health.value != "fault", plant.drivers["rio"].fault_reason
            start_test(plant, lambda: slave.set_input(0, 1), lambda: slave.set_input(1, 1),
                       lambda: slave.output(0) == 1 and slave.output(3) == 1, settle=True)
        finally:
            plant.close()
        assert wait_until(lambda: slave.output(0) == 0)


def test_modbus_module(tmp_path: Path) -> None:
    pdef = load_plant(layout(tmp_path, "modbus_module"))
    # a pty has no parity: the driver's 8E1 is accepted, pymodbus' serial code refuses it
    with PtyBridge() as bridge, ModbusPeer(bridge.peer_port, units=(1,), baudrate=19200) as peer:
        pdef.drivers["mb"].config["port"] = bridge.driver_port
        plant = Plant(pdef)
        plant.open()
        try:
            assert plant.drivers["mb"].ok, plant.drivers["mb"].fault_reason
            start_test(plant, lambda: peer.set(1, 2, 0, [1]), lambda: peer.set(1, 2, 1, [1]),
                       lambda: peer.get(1, 1, 0, 4) == [1, 0, 0, 1], settle=True)
        finally:
            plant.close()
        assert peer.get(1, 1, 0, 4) == [0, 0, 0, 0]


@pytest.mark.parametrize("name", ["pi_mcp23017", "canopen_node", "modbus_module"])
def test_wiring_is_documented(tmp_path: Path, name: str) -> None:
    """The header of each example plant has one wiring line per bound point, naming the
    variable; inputs say their contact (NC inverted by the binding, NO not)."""
    text = (CONFIGS / name / "plant.yaml").read_text(encoding="utf-8")
    header = [line[1:] for line in text.splitlines() if line.startswith("#")]
    pdef = load_plant(layout(tmp_path, name))
    for idef in pdef.instances.values():
        for section, is_input in ((idef.inputs, True), (idef.outputs, False)):
            for var, b in section.items():
                rows = [h for h in header if re.search(rf"\b{re.escape(b.point or '')}\b", h)
                        and re.search(rf"\b{var}\b", h)]
                assert len(rows) == 1, f"{name}: no wiring line for {var} on {b.source}"
                words = rows[0].split()
                if is_input:
                    assert ("NC" in words and "invert" in words) == b.invert, rows[0]
                    assert ("NO" in words) == (not b.invert), rows[0]
