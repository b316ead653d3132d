"""The contract suite's rigs (tests/drivers/rigs.py) on the kernel's own devices: the gpio
driver on a gpio-sim chip (named by its label), the mcp23017 driver on an i2c-stub chip,
the canopen driver over SocketCAN on a vcan interface with the suite's CiA 401 node."""

from __future__ import annotations

from typing import Any

import pytest
from canopen.sdo.client import SdoClient

import tests.drivers.rigs as contract_rigs
from drivers.base import Driver
from drivers.canopen_io import CanopenDriver
from drivers.gpio import GpioDriver
from drivers.mcp23017 import GPIOA, OLATA, Mcp23017Driver
from tests.drivers.canopen_slave import Cia401Slave
from tests.drivers.drvkit import FakeClock
from tests.drivers.rigs import CanopenRig, GpioRig, McpRig, Rig
from tests.kernel_io.kio import STUB_ADDRESSES, SimChip, StubChip, Vcan


class SimGpioRig(Rig):
    """A gpio-sim chip of its own; the bus breaks as the chip is removed, and heals as it
    comes back (under a new number: the driver finds it by its label)."""

    inputs = ("2", "3")
    outputs = ("6", "7")
    bad_points = GpioRig.bad_points

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        super().__init__(mp, clock)
        self.chip = SimChip()

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return GpioDriver("gpio", {"chip": self.chip.label, **cfg}, clock=self.clock)

    def set_input(self, point: str, value: int) -> None:
        self.chip.pull(int(point), value)

    def output(self, point: str) -> int:
        return self.chip.value(int(point))

    def break_bus(self, d: Driver) -> None:
        self.chip.remove()

    def heal_bus(self, d: Driver) -> None:
        self.chip.restore()

    def close(self) -> None:
        self.chip.destroy()


class StubMcpRig(McpRig):
    """An MCP23017 on the i2c-stub chip at 0x20, its registers zeroed (a chip at power-on
    would hold IODIR 0xFF: the driver sets every register it relies on). An input is a bit
    the test pokes into GPIOA/GPIOB; an output the bit the driver wrote to OLATA/OLATB. The
    stub always answers: its bus cannot break."""

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        Rig.__init__(self, mp, clock)
        self.stub = StubChip(STUB_ADDRESSES[0])
        self.stub.zero()

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return Mcp23017Driver("exp1", {"bus": self.stub.bus_number,
                                       "address": self.stub.address, **cfg}, clock=self.clock)

    @staticmethod
    def _bit(point: str) -> tuple[int, int]:
        """(port offset, bit) of A0-B7."""
        return (0 if point[0] == "A" else 1), 1 << int(point[1])

    def set_input(self, point: str, value: int) -> None:
        port, bit = self._bit(point)
        now = self.stub.peek(GPIOA + port)
        self.stub.poke(GPIOA + port, now | bit if value else now & ~bit)

    def output(self, point: str) -> int:
        port, bit = self._bit(point)
        return 1 if self.stub.peek(OLATA + port) & bit else 0

    def close(self) -> None:
        self.stub.close()


class VcanCanopenRig(CanopenRig):
    """The suite's CiA 401 node and the driver on a vcan interface of their own: real
    SocketCAN sockets, frames through the kernel's CAN layer.

    The node and the driver's receive and configuration threads run in real time on an
    emulated processor, on a machine shared with other work: the waits that are real time
    (an SDO answer, the first exchange after open, the rig's settling) are given
    ``SLOW_S``; the driver's own times (heartbeat age, back-off) stay on the injected
    clock, as in tests/drivers."""

    #: seconds a real-time wait may take in the guest
    SLOW_S = 20.0
    #: the driver waits two heartbeats in real time for OPERATIONAL after its NMT start:
    #: at tests/drivers' 0.2 s that wait (400 ms) ran out once in the guest under load
    #: (test_one_log_line_per_state_change[canopen-vcan]); the tests' own heartbeat times
    #: are on the injected clock and scale with it
    HEARTBEAT_S = 1.0

    def __init__(self, mp: pytest.MonkeyPatch, clock: FakeClock) -> None:
        Rig.__init__(self, mp, clock)
        mp.setattr(SdoClient, "RESPONSE_TIMEOUT", self.SLOW_S / 4)
        mp.setattr(CanopenDriver, "FIRST_DATA_TIMEOUT_S", self.SLOW_S)
        mp.setattr(contract_rigs, "SETTLE_S", self.SLOW_S)
        self.vcan = Vcan()
        self.slave = Cia401Slave(5, interface="socketcan", channel=self.vcan.name).start()

    def _make(self, cfg: dict[str, Any]) -> Driver:
        return CanopenDriver("rio", {"interface": "socketcan", "channel": self.vcan.name,
                                     "node": 5, "heartbeat": self.HEARTBEAT_S, **cfg},
                             clock=self.clock)

    def close(self) -> None:
        super().close()
        self.vcan.delete()


#: kernel rig name -> rig
KERNEL_RIGS: dict[str, type[Rig]] = {
    "gpio-sim": SimGpioRig,
    "mcp23017-i2c-stub": StubMcpRig,
    "canopen-vcan": VcanCanopenRig,
}
