"""CANopen driver against a simulated CiA 401 node on python-can's virtual bus; and once
against the node in another process over udp_multicast, inside a private network
namespace."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator

import can
import canopen
import pytest

from drivers.base import Direction, Health, PointError
from drivers.canopen_io import CanopenDriver
from drivers.config import ConfigError
from tests.drivers.canopen_slave import OPERATIONAL, PRE_OPERATIONAL, Cia401Slave
from tests.drivers.drvkit import FakeClock, wait_until

HERE = os.path.dirname(__file__)


@pytest.fixture
def channel() -> str:
    return f"softplc-{uuid.uuid4().hex[:8]}"


@pytest.fixture
def slave(channel: str) -> Iterator[Cia401Slave]:
    with Cia401Slave(5, channel=channel) as s:
        yield s


def make(channel: str, clock: FakeClock, inputs: tuple[str, ...] = ("I0", "I3", "I9"),
         outputs: tuple[str, ...] = ("Q1", "Q10"), **cfg: object) -> CanopenDriver:
    config = {"interface": "virtual", "channel": channel, "node": 5, "heartbeat": "200ms",
              **cfg}
    d = CanopenDriver("rio", config, clock=clock)
    for p in inputs:
        d.add_point(p, Direction.IN)
    for p in outputs:
        d.add_point(p, Direction.OUT)
    return d


def drain(d: CanopenDriver, slave: Cia401Slave) -> None:
    """Wait until the driver's receive thread has handled every frame sent so far."""
    seen = threading.Event()
    assert d._network is not None
    d._network.subscribe(0x7F0, lambda *_: seen.set())
    slave.network.send_message(0x7F0, b"")
    assert seen.wait(3.0)
    d._network.unsubscribe(0x7F0)


def scanned(d: CanopenDriver) -> CanopenDriver:
    """The driver after one scan's read()."""
    d.read()
    return d


def settle(d: CanopenDriver, health: Health = Health.OK) -> None:
    """Scan (read) until the driver reports ``health``: effects of other threads only."""
    assert wait_until(lambda: scanned(d).health is health), (d.health, d.fault_reason)


def test_open_maps_by_sdo_sets_heartbeat_and_starts(slave: Cia401Slave, channel: str,
                                                    clock: FakeClock) -> None:
    slave.set_input(3, 1)  # before start: sent on entering OPERATIONAL
    d = make(channel, clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    assert slave.state == OPERATIONAL and slave.nmt_log == [0x01]
    assert slave._u(0x1017, 0) == 50  # a quarter of the 200 ms consumer timeout
    settle(d)
    assert d.inputs == {"I0": 0, "I3": 1, "I9": 0}
    d.close()
    d.close()
    assert d.health is Health.CLOSED


def test_pdo_exchange_both_ways(slave: Cia401Slave, channel: str, clock: FakeClock) -> None:
    d = make(channel, clock)
    d.open()
    slave.set_input(9, 1)
    assert wait_until(lambda: scanned(d).inputs["I9"] == 1)
    d.outputs.update({"Q1": True, "Q10": 1})
    d.write()
    assert wait_until(lambda: slave.output(1) == 1 and slave.output(10) == 1)
    assert slave.output(0) == 0 and slave.output(9) == 0
    d.safe_state()
    assert wait_until(lambda: slave.output(1) == 0 and slave.output(10) == 0)
    d.outputs["Q1"] = 1
    d.write()
    assert wait_until(lambda: slave.output(1) == 1)
    d.close()  # close writes the safe state first
    assert wait_until(lambda: slave.output(1) == 0)


def test_mapping_over_two_tpdos_with_other_objects(channel: str, clock: FakeClock) -> None:
    tpdos = [[(0x6000, 1, 8)], [(0x2000, 0, 16), (0x6000, 2, 8)]]
    with Cia401Slave(5, channel=channel, tpdos=tpdos, extra=(0x2000,)) as slave:
        d = make(channel, clock)
        d.open()
        slave.set_input(9, 1)  # 0x6000:2 bit 1: TPDO2 byte 2
        slave.set_input(0, 1)
        assert wait_until(lambda: scanned(d).inputs == {"I0": 1, "I3": 0, "I9": 1})
        d.close()


def test_heartbeat_loss_and_return(slave: Cia401Slave, channel: str, clock: FakeClock) -> None:
    d = make(channel, clock, on_fault="hold")
    d.open()
    slave.set_input(0, 1)
    assert wait_until(lambda: scanned(d).inputs["I0"] == 1)
    slave.heartbeat_paused = True
    drain(d, slave)
    clock.advance(0.21)
    d.read()
    assert d.health is Health.FAULT and "heartbeat lost" in (d.fault_reason or "")
    assert d.inputs["I0"] == 1  # hold
    clock.advance(d.RECONNECT_MIN_S)
    d.read()  # a restart is tried: NMT start, then no heartbeat: it fails
    assert d._configurator is not None
    d._configurator.join()
    assert slave.nmt_log == [0x01, 0x01]
    d.read()
    assert d.health is Health.FAULT
    assert "no heartbeat in OPERATIONAL" in (d.fault_reason or "")
    slave.heartbeat_paused = False  # the node never left OPERATIONAL ...
    drain(d, slave)
    assert wait_until(lambda: d._hb_state == OPERATIONAL)
    d.read()
    assert d.health is Health.FAULT  # ... yet only a restart makes the driver OK again
    clock.advance(d.RECONNECT_MAX_S)
    settle(d)
    assert slave.nmt_log == [0x01, 0x01, 0x01]
    d.close()


def test_cable_cut_inputs_changed_meanwhile_are_read_again(channel: str,
                                                           clock: FakeClock) -> None:
    # the node keeps running while its cable is cut; the input that changed meanwhile had
    # its TPDO lost, and this node sends no TPDO on (re)entering OPERATIONAL
    with Cia401Slave(5, channel=channel, tpdo_on_start=False) as slave:
        d = make(channel, clock, on_fault="hold")
        d.open()
        d.outputs["Q1"] = 1
        d.write()
        assert wait_until(lambda: slave.output(1) == 1)
        slave.cut_cable()
        slave.set_input(9, 1)
        drain(d, slave)
        clock.advance(0.21)
        d.read()
        assert d.health is Health.FAULT and "heartbeat lost" in (d.fault_reason or "")
        slave.mend_cable()
        assert slave.state == OPERATIONAL
        clock.advance(d.RECONNECT_MIN_S)
        settle(d)
        assert d.inputs["I9"] == 1  # read by SDO at the restart
        d.write()
        assert slave.output(1) == 1
        d.close()


def test_inputs_known_at_open_without_tpdo_on_start(channel: str, clock: FakeClock) -> None:
    with Cia401Slave(5, channel=channel, tpdo_on_start=False) as slave:
        slave.set_input(3, 1)
        slave.set_input(9, 1)
        d = make(channel, clock)
        d.open()
        assert d.health is Health.OK, d.fault_reason
        d.read()
        assert d.inputs == {"I0": 0, "I3": 1, "I9": 1}
        slave.set_input(3, 0)  # and TPDOs keep them from then on
        assert wait_until(lambda: scanned(d).inputs["I3"] == 0)
        d.close()


def test_tpdo_during_the_sdo_read_of_inputs_wins(slave: Cia401Slave, channel: str,
                                                 clock: FakeClock) -> None:
    d = make(channel, clock)
    d.open()
    assert d._node is not None
    node = d._node
    real_upload = node.sdo.upload

    def upload_then_input_changes(index: int, subindex: int) -> bytes:
        data = real_upload(index, subindex)
        if index == 0x6000 and subindex == 1:
            slave.set_input(3, 0)  # a TPDO after the SDO answer, before it is published
            drain(d, slave)
        return data

    slave.set_input(3, 1)
    assert wait_until(lambda: scanned(d).inputs["I3"] == 1)
    node.sdo.upload = upload_then_input_changes  # type: ignore[method-assign]
    d._read_inputs()
    d.read()
    assert d.inputs["I3"] == 0
    d.close()


def test_node_lost_and_back_is_started_again_after_back_off(
    slave: Cia401Slave, channel: str, clock: FakeClock
) -> None:
    d = make(channel, clock, on_fault="zero")
    d.open()
    slave.set_input(3, 1)
    d.outputs["Q10"] = 1
    d.write()
    assert wait_until(lambda: scanned(d).inputs["I3"] == 1 and slave.output(10) == 1)
    slave.power_off()
    drain(d, slave)
    clock.advance(0.21)
    d.read()
    assert d.health is Health.FAULT and d.inputs["I3"] == 0  # zero
    slave.power_on()  # boot-up, PRE-OPERATIONAL, outputs off
    assert wait_until(lambda: slave.state == PRE_OPERATIONAL)
    drain(d, slave)
    d.read()
    assert d.health is Health.FAULT  # back-off: not restarted yet
    assert slave.nmt_log == [0x01]
    clock.advance(d.RECONNECT_MIN_S)
    settle(d)
    assert slave.state == OPERATIONAL and slave.nmt_log == [0x01, 0x01]
    d.write()  # outputs sent again after recovery
    assert wait_until(lambda: slave.output(10) == 1)
    assert wait_until(lambda: scanned(d).inputs["I3"] == 1)
    d.close()


def test_reboot_seen_before_the_heartbeat_timeout(slave: Cia401Slave, channel: str,
                                                  clock: FakeClock) -> None:
    d = make(channel, clock)
    d.open()
    slave.power_off()
    slave.power_on()  # a quick reboot: the boot-up message says it all
    drain(d, slave)
    d.read()
    assert d.health is Health.FAULT and "boot-up" in (d.fault_reason or "")
    clock.advance(d.RECONNECT_MIN_S)
    settle(d)
    d.close()


def test_sync_mode_sends_on_change_and_node_applies_on_sync(channel: str,
                                                            clock: FakeClock) -> None:
    with Cia401Slave(5, channel=channel, transmission=1) as slave:
        d = make(channel, clock, sync="10ms")
        rpdos: list[bytes] = []
        slave.network.subscribe(0x205, lambda _i, data, _t: rpdos.append(bytes(data)))
        d.open()
        assert d.health is Health.OK, d.fault_reason
        assert wait_until(lambda: slave.syncs > 0)
        for _ in range(5):
            d.write()
        d.outputs["Q1"] = 1
        for _ in range(5):
            d.write()
        assert wait_until(lambda: slave.output(1) == 1)
        assert rpdos == [b"\x00\x00", b"\x02\x00"]  # first image, then the change only
        slave.set_input(3, 1)  # a synchronous TPDO: sent at the next SYNC
        assert wait_until(lambda: scanned(d).inputs["I3"] == 1)
        d.close()


def test_mapping_from_config_without_sdo(slave: Cia401Slave, channel: str,
                                         clock: FakeClock) -> None:
    d = make(channel, clock, pdo={"tpdo1": ["6000:1", "6000:2"],
                                  "rpdo1": ["6200:1", "6200:2"]})
    d.open()
    slave.set_input(9, 1)
    assert wait_until(lambda: scanned(d).inputs["I9"] == 1)
    d.outputs["Q10"] = 1
    d.write()
    assert wait_until(lambda: slave.output(10) == 1)
    d.close()


def test_mapping_from_eds(slave: Cia401Slave, channel: str, clock: FakeClock,
                          tmp_path: object) -> None:
    path = os.path.join(str(tmp_path), "node5.eds")
    canopen.export_od(slave.od, path)
    d = make(channel, clock, eds=path)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    slave.set_input(0, 1)
    assert wait_until(lambda: scanned(d).inputs["I0"] == 1)
    d.close()


def test_point_not_mapped_is_a_fault_at_open(slave: Cia401Slave, channel: str,
                                             clock: FakeClock) -> None:
    d = make(channel, clock, inputs=("I40",), outputs=())
    d.open()
    assert d.health is Health.FAULT
    assert "I40 (6000:06) is mapped in no enabled TPDO" in (d.fault_reason or "")
    d.close()


def test_absent_node(channel: str, clock: FakeClock) -> None:
    d = make(channel, clock)
    d.open()
    assert d.health is Health.FAULT and "node 5" in (d.fault_reason or "")
    d.close()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_receive_thread_errors(slave: Cia401Slave, channel: str, clock: FakeClock) -> None:
    d = make(channel, clock)
    d.open()
    assert d._tpdos is not None
    d._tpdos[0].bits.append((99, 0, "I0"))  # a bug in decoding
    slave.set_input(0, 1)
    assert wait_until(lambda: d._io_error is not None)
    with pytest.raises(IndexError):
        d.read()
    d.close()
    # a bus whose reception fails (interface down) is a fault, then a new connection
    d = make(channel, clock)
    d.open()
    assert d._network is not None and d._network.bus is not None

    def down(timeout: float | None = None) -> None:
        raise can.CanOperationError("interface down")

    d._network.bus.recv = down  # type: ignore[method-assign]
    assert wait_until(lambda: scanned(d).health is Health.FAULT)
    assert "receiving stopped: interface down" in (d.fault_reason or "")
    clock.advance(d.RECONNECT_MIN_S)
    settle(d)
    d.close()


@pytest.mark.parametrize("point,direction", [("I0", Direction.OUT), ("Q0", Direction.IN),
                                             ("I64", Direction.IN), ("X1", Direction.IN),
                                             ("i1", Direction.IN)])
def test_bad_points(point: str, direction: Direction) -> None:
    d = CanopenDriver("rio", {"node": 5})
    with pytest.raises(PointError):
        d.add_point(point, direction)


@pytest.mark.parametrize("cfg", [{}, {"node": 0}, {"node": 5, "heartbeat": "soon"},
                                 {"node": 5, "sync": 0}, {"node": 5, "pdo": {"tpdo9": []}},
                                 {"node": 5, "pdo": {"tpdo1": ["6000"]}},
                                 {"node": 5, "speed": 1}])
def test_bad_config(cfg: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        CanopenDriver("rio", cfg)


# -- the node in another process, over udp_multicast, inside a private network namespace ---
def _netns_reason() -> str | None:
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "needs unshare and ip (util-linux, iproute2)"
    try:
        import msgpack  # noqa: F401  (python-can's udp_multicast needs it)
    except ImportError:
        return "python-can's udp_multicast needs msgpack (pip install 'python-can[multicast]')"
    probe = subprocess.run(["unshare", "-rn", "sh", "-c", "ip link set lo up"],
                           capture_output=True, text=True, timeout=10)
    if probe.returncode != 0:
        return f"cannot make a private network namespace here: {probe.stderr.strip()}"
    return None


NETNS_REASON = _netns_reason()


@pytest.mark.skipif(NETNS_REASON is not None, reason=NETNS_REASON or "")
def test_node_in_another_process_over_udp_multicast() -> None:
    # Multicast never leaves the namespace: only its loopback exists, and it is the route.
    script = (
        "set -e; ip link set lo up; ip link set lo multicast on; "
        "ip route add 224.0.0.0/4 dev lo; "
        f"exec {sys.executable} {os.path.join(HERE, 'canopen_netns_scenario.py')}"
    )
    env = {**os.environ, "PYTHONPATH": os.path.dirname(os.path.dirname(HERE))}
    run = subprocess.run(["unshare", "-rn", "sh", "-c", script], capture_output=True,
                         text=True, timeout=60, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["opened"] == "ok", result
    assert result["round_trip"] is True, result
    assert result["lost"] == "fault" and "heartbeat lost" in result["lost_reason"], result
    assert result["back"] == "ok", result
