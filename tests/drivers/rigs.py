"""One test rig per driver type for the contract suite: the driver on its peer or emulator,
with a way to drive inputs, see outputs, break the bus and heal it."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

import gpiod
import pytest
import smbus2

from drivers.base import Direction, Driver, DriverError, Health, PolledDriver
from drivers.canopen_io import CanopenDriver
from drivers.gpio import GpioDriver
from drivers.mcp23017 import Mcp23017Driver
from drivers.modbus_rtu import ModbusRtuDriver
from drivers.modbus_tcp import ModbusTcpDriver
from drivers.pcf8574 import Pcf8574Driver
from drivers.sim import SimDriver
from tests.drivers.canopen_slave import Cia401Slave
from tests.drivers.drvkit import FakeClock
from tests.drivers.fake_gpiod import FakeChip, FakeGpio
from tests.drivers.i2c_emulator import I2CWorld, Mcp23017Model, Pcf8574Model
from tests.drivers.pty_bridge import PtyBridge

#: seconds any condition that depends on another thread may take: a bound only a driver
#: that hangs reaches (every wait on it ends as soon as its condition holds); 3 s was
#: reached at a load of 10-18 on 2 cores (test_inhibited_driver_never_energises[modbus_rtu])
SETTLE_S = 30.0


class Rig:
    """The driver type's peer. Subclasses fill in the hooks."""

    inputs: tuple[str, str] = ("I0", "I1")
    outputs: tuple[str, str] = ("Q0", "Q1")
    #: (point, direction) pairs that add_point must refuse
    bad_points: tuple[tuple[str, Direction], ...] = ()

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        self.mp = mp
        self.clock = clock
        #: every driver made, closed by ``close_drivers`` (close is idempotent): a test
        #: that fails before its own close must not leave a shared link to the next test
        self.made: list[Driver] = []

    def close_drivers(self) -> None:
        for d in self.made:
            d.close()

    def make(self, **cfg: Any) -> Driver:
        d = self._make(cfg)
        self.made.append(d)
        for p in self.inputs:
            d.add_point(p, Direction.IN)
        for p in self.outputs:
            d.add_point(p, Direction.OUT)
        return d

    def _make(self, cfg: dict[str, Any]) -> Driver:  # pragma: no cover
        raise NotImplementedError

    def set_input(self, point: str, value: int) -> None:  # pragma: no cover
        raise NotImplementedError

    def output(self, point: str) -> int:  # pragma: no cover
        raise NotImplementedError

    def break_bus(self, d: Driver) -> None:  # pragma: no cover
        raise NotImplementedError

    def heal_bus(self, d: Driver) -> None:  # pragma: no cover
        raise NotImplementedError

    def close(self) -> None:
        pass

    # -- scanning ---------------------------------------------------------------------------
    def scan(self, d: Driver) -> None:
        """One cycle (read, write); for a polled driver, wait for the exchange it started."""
        if isinstance(d, PolledDriver):
            since = d.updates
            d.read()
            if d.health is Health.FAULT:
                return  # nothing is exchanged until the back-off allows a retry
            d.write()
            d.wait_for_update(0.5, since=since)
        else:
            d.read()
            d.write()

    def until(self, d: Driver, cond: Callable[[], bool]) -> bool:
        """Scan until ``cond`` holds (at once for a driver that works in the scan)."""
        deadline = time.monotonic() + SETTLE_S
        while True:
            self.scan(d)
            if cond():
                return True
            if time.monotonic() > deadline:
                return False
            time.sleep(0.002)

    def fault(self, d: Driver) -> None:
        """Break the bus and scan until the driver reports the fault."""
        self.break_bus(d)
        assert self.until(d, lambda: d.health is Health.FAULT), d.health

    def settle_retry(self, d: Driver, since: int) -> None:
        """After a retry was asked for (``since``: the driver's updates before): let its
        attempt finish."""


class SimRig(Rig):
    def _make(self, cfg: dict[str, Any]) -> Driver:
        self.d = SimDriver("sim", cfg, clock=self.clock)
        return self.d

    def set_input(self, point: str, value: int) -> None:
        self.d.set_input(point, value)

    def output(self, point: str) -> int:
        return int(self.d.written.get(point, 0))

    def break_bus(self, d: Driver) -> None:
        def broken() -> None:
            raise DriverError("sim: injected fault")

        self.mp.setattr(d, "_read", broken)
        self.mp.setattr(d, "_open", broken)

    def heal_bus(self, d: Driver) -> None:
        self.mp.undo()


class GpioRig(Rig):
    inputs = ("17", "27")
    outputs = ("22", "23")
    bad_points = (("GPIO17", Direction.IN), ("99999", Direction.OUT))

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        super().__init__(mp, clock)
        self.kernel = FakeGpio(clock)
        self.chip: FakeChip = self.kernel.add_chip("/dev/gpiochip0", 54)
        mp.setattr(gpiod, "request_lines", self.kernel.request_lines)

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return GpioDriver("gpio", {"chip": "/dev/gpiochip0", **cfg}, clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.chip.drive(int(point), value)

    def output(self, point: str) -> int:
        return self.chip.level(int(point))

    def break_bus(self, d: Driver) -> None:
        self.chip.removed = True

    def heal_bus(self, d: Driver) -> None:
        self.chip.removed = False


class McpRig(Rig):
    inputs = ("A0", "A1")
    outputs = ("B0", "B1")
    bad_points = (("C0", Direction.IN), ("A8", Direction.OUT))

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        super().__init__(mp, clock)
        self.world = I2CWorld()
        self.chip = Mcp23017Model(0x20)
        self.world.bus(1).add(self.chip)
        mp.setattr(smbus2, "SMBus", self.world.smbus_class)

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return Mcp23017Driver("exp1", {"bus": 1, "address": 0x20, **cfg}, clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.chip.drive(point, value)

    def output(self, point: str) -> int:
        return self.chip.pin(point)

    def break_bus(self, d: Driver) -> None:
        self.chip.power_off()

    def heal_bus(self, d: Driver) -> None:
        self.chip.power_on()


class PcfRig(McpRig):
    inputs = ("P0", "P1")
    outputs = ("P4", "P5")
    bad_points = (("P8", Direction.IN), ("A0", Direction.OUT))

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        Rig.__init__(self, mp, clock)
        self.world = I2CWorld()
        self.pcf = Pcf8574Model(0x38)
        self.world.bus(1).add(self.pcf)
        mp.setattr(smbus2, "SMBus", self.world.smbus_class)

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return Pcf8574Driver("exp2", {"bus": 1, "address": 0x38, **cfg}, clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.pcf.drive(int(point[1]), value)

    def output(self, point: str) -> int:
        return self.pcf.pin(int(point[1]))

    def break_bus(self, d: Driver) -> None:
        self.pcf.power_off()

    def heal_bus(self, d: Driver) -> None:
        self.pcf.power_on()


class CanopenRig(Rig):
    inputs = ("I0", "I9")
    outputs = ("Q1", "Q10")
    bad_points = (("I0", Direction.OUT), ("Q64", Direction.OUT))
    HEARTBEAT_S = 0.2

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        super().__init__(mp, clock)
        self.channel = f"softplc-{uuid.uuid4().hex[:8]}"
        self.slave = Cia401Slave(5, channel=self.channel).start()

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return CanopenDriver("rio", {"interface": "virtual", "channel": self.channel,
                                     "node": 5, "heartbeat": self.HEARTBEAT_S, **cfg},
                             clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.slave.set_input(int(point[1:]), value)

    def output(self, point: str) -> int:
        return self.slave.output(int(point[1:]))

    def scan(self, d: Driver) -> None:
        d.read()  # TPDOs come when inputs change: there is no exchange to wait for
        d.write()

    def _drain(self, d: Driver) -> None:
        assert isinstance(d, CanopenDriver) and d._network is not None
        seen = threading.Event()
        d._network.subscribe(0x7F0, lambda *_: seen.set())
        self.slave.network.send_message(0x7F0, b"")
        assert seen.wait(SETTLE_S)
        d._network.unsubscribe(0x7F0)

    def break_bus(self, d: Driver) -> None:
        self.slave.power_off()
        self._drain(d)
        self.clock.advance(self.HEARTBEAT_S * 1.05)

    def heal_bus(self, d: Driver) -> None:
        self.slave.power_on()
        self._drain(d)

    def settle_retry(self, d: Driver, since: int) -> None:
        assert isinstance(d, CanopenDriver)
        thread = d._configurator
        if thread is not None:
            thread.join(SETTLE_S)

    def close(self) -> None:
        self.slave.stop()


class ModbusRig(Rig):
    bad_points = (("I0", Direction.OUT), ("R1", Direction.IN))

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        super().__init__(mp, clock)
        # imported here: pymodbus is the heaviest import of the rigs, and the kernel_io
        # tier's rigs (tests/kernel_io/rigs.py), which build on these, need none of it
        from tests.drivers.modbus_peer import ModbusPeer

        self.bridge = PtyBridge()
        self.peer = ModbusPeer(self.bridge.peer_port, units=(1,)).start()

    def _make(self, cfg: dict[str, Any]) -> Driver:
        # a reply timeout a loaded machine holds (the peer and the bridge are threads of
        # this process): the contract is not about its timing
        return ModbusRtuDriver("mb", {"port": self.bridge.driver_port, "unit": 1,
                                      "baudrate": 115200, "timeout": "300ms", "retries": 1,
                                      **cfg}, clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.peer.set(1, 2, int(point[1:]), [value])

    def output(self, point: str) -> int:
        return self.peer.get(1, 1, int(point[1:]))[0]

    def break_bus(self, d: Driver) -> None:
        self.bridge.cut = True

    def heal_bus(self, d: Driver) -> None:
        self.bridge.cut = False

    def settle_retry(self, d: Driver, since: int) -> None:
        assert isinstance(d, PolledDriver)
        assert d.wait_for_update(SETTLE_S, since=since)

    def close(self) -> None:
        self.peer.stop()
        self.bridge.close()


class ModbusTcpRig(ModbusRig):
    """pymodbus' TCP server behind a relay that drops every reply while the bus is broken
    (a unit that stops answering on a connection that stays up)."""

    bad_points = (("IR0", Direction.OUT), ("R1", Direction.IN))

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        Rig.__init__(self, mp, clock)
        # pymodbus imported by the Modbus rigs only (a third of the kernel tier's
        # collection time in the guest otherwise)
        from tests.drivers.modbus_tcp_peer import ModbusTcpPeer, Relay
        self.tcp = ModbusTcpPeer(units=(1,)).start()
        self.relay = Relay(self.tcp.port)

    def _make(self, cfg: dict[str, Any]) -> Driver:
        # a reply timeout a loaded machine holds (the peer and the relay are threads of
        # this process: 30 ms timed out at open under two suites and QEMU on 2 cores)
        return ModbusTcpDriver("rio", {"host": "127.0.0.1", "port": self.relay.port,
                                       "unit": 1, "timeout": "300ms", "retries": 1, **cfg},
                               clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.tcp.set(1, 2, int(point[1:]), [value])

    def output(self, point: str) -> int:
        return self.tcp.get(1, 1, int(point[1:]))[0]

    def break_bus(self, d: Driver) -> None:
        self.relay.cut = True

    def heal_bus(self, d: Driver) -> None:
        self.relay.cut = False

    def close(self) -> None:
        self.close_drivers()  # the gateways are shared by the process (shared_gateways)
        self.relay.close()
        self.tcp.stop()


RIGS: dict[str, type[Rig]] = {
    "sim": SimRig,
    "gpio": GpioRig,
    "mcp23017": McpRig,
    "pcf8574": PcfRig,
    "canopen": CanopenRig,
    "modbus_rtu": ModbusRig,
    "modbus_tcp": ModbusTcpRig,
}
