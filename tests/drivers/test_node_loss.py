"""A lost I/O node, seen through the plant (runtime.engine.plant) as each ``on_fault`` policy says:
a CiA 401 node on python-can's virtual bus powers off in the middle of a run.

The chart follows one input of the node (iA) to an output of the node and to a panel lamp,
and lights an alarm while ``rio.ok`` is false. Time is the injected clock of the driver
(heartbeat age, back-off) and the ``now`` given to ``Plant.cycle``: nothing sleeps to time
a result; waiting is only for the frames of the simulated node to cross the bus."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from drivers.base import Health
from drivers.canopen_io import CanopenDriver
from drivers.sim import SimDriver
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from tests.drivers.canopen_slave import Cia401Slave
from tests.drivers.drvkit import FakeClock, wait_until

CHART = """\
grafcet: Follower
inputs: [iA, iOk]
outputs: [oA, oEcho, oAlarm]
steps:
  gsIdle: {initial: true}
  gsOn: {actions: [oA, oEcho]}
transitions:
  - {from: gsIdle, to: gsOn, when: iA}
  - {from: gsOn, to: gsIdle, when: "iA'"}
post:
  - oAlarm := iOk'
"""

PLANT = """\
plc: {{cycle: 10ms, watchdog: 100ms}}
drivers:
  rio: {{type: canopen, interface: virtual, channel: {channel}, node: 5, heartbeat: 200ms,
         on_fault: {policy}}}
  panel: {{type: sim}}
instances:
  f1:
    grafcet: follower.yaml
    inputs:
      iA: rio.I0
      iOk: rio.ok
    outputs:
      oA: rio.Q0
      oEcho: panel.Q0
      oAlarm: panel.Q1
"""

HEARTBEAT_S = 0.2


class Rig:
    """The plant, its node, and the cycle clock."""

    def __init__(self, tmp_path: Path, policy: str, clock: FakeClock) -> None:
        channel = f"softplc-{uuid.uuid4().hex[:8]}"
        (tmp_path / "follower.yaml").write_text(CHART, encoding="utf-8")
        plant_file = tmp_path / "plant.yaml"
        plant_file.write_text(PLANT.format(channel=channel, policy=policy), encoding="utf-8")
        pdef = load_plant(str(plant_file))
        self.slave = Cia401Slave(5, channel=channel).start()
        self.clock = clock
        self.rio = CanopenDriver("rio", pdef.drivers["rio"].config, clock=clock)
        self.plant = Plant(pdef, drivers={"rio": self.rio})
        panel = self.plant.drivers["panel"]
        assert isinstance(panel, SimDriver)
        self.panel = panel
        self.now = 0

    def cycle(self) -> str | None:
        self.now += self.plant.cycle_ns
        return self.plant.cycle(self.now)

    def until(self, cond: object) -> bool:
        """Cycle until ``cond()`` (the node's frames take real time to cross the bus)."""
        assert callable(cond)
        return wait_until(lambda: (self.cycle(), cond())[1])

    def lose_node(self) -> None:
        self.slave.power_off()
        assert self.rio._network is not None
        self.slave.drain(self.rio._network)
        self.clock.advance(HEARTBEAT_S * 1.05)

    def close(self) -> None:
        self.plant.close()
        self.slave.stop()


@pytest.fixture
def rig(request: pytest.FixtureRequest, tmp_path: Path, clock: FakeClock) -> Iterator[Rig]:
    r = Rig(tmp_path, request.param, clock)
    try:
        r.plant.open()
        assert r.rio.health is Health.OK, r.rio.fault_reason
        r.slave.set_input(0, 1)
        assert r.until(lambda: r.slave.output(0) == 1 and r.panel.outputs["Q0"])
        assert not r.panel.outputs["Q1"]  # rio.ok: no alarm
        yield r
    finally:
        r.close()


@pytest.mark.parametrize("rig", ["stop"], indirect=True)
def test_stop_faults_the_plant_and_recovers_with_the_node(rig: Rig) -> None:
    scans = rig.plant.scans
    rig.lose_node()
    reason = rig.cycle()
    assert reason is not None and reason.startswith("driver rio: ")
    assert "heartbeat lost" in reason and rig.plant.faulted() == reason
    assert rig.plant.scans == scans  # no chart scanned, nothing written
    rig.plant.safe_state()  # what the caller does with a stopped cycle
    assert rig.panel.outputs == {"Q0": 0, "Q1": 0} and rig.rio.outputs == {"Q0": 0}
    for _ in range(5):
        assert rig.cycle() is not None
    assert rig.plant.scans == scans
    # the node comes back: it is started again at the driver's next back-off time
    rig.slave.power_on()
    rig.clock.advance(rig.rio.RECONNECT_MAX_S)
    assert rig.until(lambda: rig.rio.health is Health.OK), rig.rio.fault_reason
    assert rig.plant.faulted() is None
    assert rig.slave.nmt_log == [0x01, 0x01]


@pytest.mark.parametrize("rig", ["hold"], indirect=True)
def test_hold_runs_on_last_good_inputs_and_flags_it(rig: Rig) -> None:
    scans = rig.plant.scans
    rig.lose_node()
    for _ in range(5):
        assert rig.cycle() is None
    assert rig.plant.scans == scans + 5 and rig.plant.faulted() is None
    assert rig.rio.health is Health.FAULT
    assert rig.panel.outputs == {"Q0": 1, "Q1": 1}  # iA held at 1; rio.ok false: alarm
    rig.slave.power_on()
    rig.slave.set_input(0, 1)  # before the restart: read by SDO when it is started again
    rig.clock.advance(rig.rio.RECONNECT_MAX_S)
    assert rig.until(lambda: rig.rio.health is Health.OK), rig.rio.fault_reason
    assert rig.until(lambda: rig.slave.output(0) == 1)  # its outputs written again
    assert rig.panel.outputs == {"Q0": 1, "Q1": 0}


@pytest.mark.parametrize("rig", ["zero"], indirect=True)
def test_zero_runs_with_the_node_inputs_at_0(rig: Rig) -> None:
    rig.lose_node()
    assert rig.cycle() is None
    assert rig.rio.inputs == {"I0": 0}
    assert rig.cycle() is None  # the chart saw iA = 0 and left gsOn
    assert rig.panel.outputs == {"Q0": 0, "Q1": 1}
    assert rig.plant.faulted() is None
