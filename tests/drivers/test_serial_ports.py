"""The owner of the shared serial lines (drivers.serial_line.SerialPorts): a line lives from
its port's first driver to its last, and a test may give its drivers their own owner."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from drivers.base import Direction, DriverError, Health
from drivers.modbus_rtu import ModbusRtuDriver
from drivers.serial_line import SerialPorts, shared_ports
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

FAST = {"baudrate": 115200, "timeout": "50ms", "retries": 1}


@pytest.fixture
def bridge() -> Iterator[PtyBridge]:
    with PtyBridge() as b:
        yield b


@pytest.fixture
def peer(bridge: PtyBridge) -> Iterator[ModbusPeer]:
    with ModbusPeer(bridge.peer_port, units=(1, 2)) as p:
        yield p


def make(bridge: PtyBridge, ports: SerialPorts | None, unit: int = 1,
         **cfg: object) -> ModbusRtuDriver:
    d = ModbusRtuDriver(f"mb{unit}", {"port": bridge.driver_port, "unit": unit, **FAST, **cfg},
                        ports=ports)
    d.add_point("I0", Direction.IN)
    d.add_point("Q0", Direction.OUT)
    return d


def _poll_threads(port: str) -> int:
    return [t.name for t in threading.enumerate()].count(f"modbus-rtu {port}")


def test_own_ports_open_and_close_repeatedly_without_leaks(bridge: PtyBridge,
                                                           peer: ModbusPeer) -> None:
    ports = SerialPorts()
    for _ in range(3):
        a, b = make(bridge, ports, 1), make(bridge, ports, 2)
        a.open()
        b.open()
        assert a.health is Health.OK and b.health is Health.OK
        assert a.line is b.line and ports.ports() == [bridge.driver_port]
        assert not shared_ports().ports()  # the process's own owner saw nothing
        assert _poll_threads(bridge.driver_port) == 1
        a.close()
        assert ports.ports() == [bridge.driver_port]  # b still holds the port
        b.close()
        assert ports.ports() == []
        assert _poll_threads(bridge.driver_port) == 0


def test_drivers_share_the_process_ports_by_default(bridge: PtyBridge, peer: ModbusPeer) -> None:
    d = make(bridge, None)
    assert d.ports is shared_ports()
    d.open()
    assert shared_ports().ports() == [bridge.driver_port]
    d.close()
    assert shared_ports().ports() == []


def test_a_port_cannot_be_opened_under_two_settings(bridge: PtyBridge,
                                                    peer: ModbusPeer) -> None:
    ports = SerialPorts()
    a = make(bridge, ports, 1)
    b = make(bridge, ports, 2, parity="E")
    a.open()
    with pytest.raises(DriverError, match="is used by another driver with"):
        ports.attach(b)
    a.close()
    assert ports.ports() == []
