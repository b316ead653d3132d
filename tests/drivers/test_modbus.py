"""Modbus RTU master: frames byte by byte, then against a pymodbus RTU server on a pty pair
(shared port, exceptions, garbled bytes, a server killed and restarted)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymodbus.constants import ExcCodes

from drivers.base import Direction, Health, PointError, PolledDriver
from drivers.config import ConfigError
from drivers.modbus_frame import (
    crc16,
    decode_reply,
    read_request,
    response_length,
    write_coils_request,
    write_registers_request,
)
from drivers.modbus_rtu import ModbusRtuDriver
from drivers.serial_line import shared_ports
from tests.drivers.drvkit import FakeClock
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

HERE = os.path.dirname(__file__)
FAST: dict[str, Any] = {"baudrate": 115200, "timeout": "50ms", "retries": 1}


# -- frames ----------------------------------------------------------------------------------
def test_crc_and_requests_match_the_specification() -> None:
    # Modbus over serial line v1.02, and the classic "01 03 00 00 00 0A C5 CD"
    assert read_request(1, 3, 0, 10) == bytes.fromhex("01030000000AC5CD")
    assert read_request(1, 2, 0, 8) == bytes.fromhex("010200000008") + crc16(
        bytes.fromhex("010200000008")).to_bytes(2, "little")
    body = bytes.fromhex("11050013FF00")
    assert write_coils_request(17, 0x13, [1]) == body + crc16(body).to_bytes(2, "little")
    # FC 15 example of the application protocol spec: 10 coils from 20 (0x13): CD 01
    bits = [1, 0, 1, 1, 0, 0, 1, 1, 1, 0]
    body = bytes.fromhex("110F0013000A02CD01")
    assert write_coils_request(0x11, 0x13, bits) == body + crc16(body).to_bytes(2, "little")
    body = bytes.fromhex("11100001000204000A0102")
    assert write_registers_request(0x11, 1, [0x000A, 0x0102]) == body + crc16(body).to_bytes(
        2, "little")
    assert write_registers_request(1, 5, [-1])[4:6] == b"\xff\xff"


def test_reply_lengths_and_decoding() -> None:
    req = read_request(1, 2, 0, 8)
    assert response_length(req) == 6
    reply = bytes.fromhex("01020108a04e")  # pymodbus' answer: input 3 on
    assert crc16(reply[:-2]) == int.from_bytes(reply[-2:], "little")
    assert decode_reply(req, reply) == [0, 0, 0, 1, 0, 0, 0, 0]
    req = read_request(1, 4, 0, 2)
    assert response_length(req) == 9
    body = bytes.fromhex("01040404D2FFFF")
    reply = body + crc16(body).to_bytes(2, "little")
    assert decode_reply(req, reply) == [1234, 65535]
    assert response_length(write_coils_request(1, 0, [1, 0, 1])) == 8


# -- against pymodbus ----------------------------------------------------------------------
@pytest.fixture
def bridge() -> Iterator[PtyBridge]:
    with PtyBridge() as b:
        yield b


@pytest.fixture
def peer(bridge: PtyBridge) -> Iterator[ModbusPeer]:
    with ModbusPeer(bridge.peer_port, units=(1, 2)) as p:
        yield p


def make(bridge: PtyBridge, clock: FakeClock, unit: int = 1, name: str = "mb",
         inputs: tuple[str, ...] = ("I0", "I1", "I3", "IR2"),
         outputs: tuple[str, ...] = ("Q0", "Q1", "HR4"), **cfg: object) -> ModbusRtuDriver:
    d = ModbusRtuDriver(name, {"port": bridge.driver_port, "unit": unit, **FAST, **cfg},
                        clock=clock)
    for p in inputs:
        d.add_point(p, Direction.IN)
    for p in outputs:
        d.add_point(p, Direction.OUT)
    return d


def scan(*drivers: PolledDriver) -> None:
    """One scan as the plant does it, waiting for the poll round the write started."""
    since = [d.updates for d in drivers]
    for d in drivers:
        d.read()  # a faulted driver asks for its retry here, when the back-off allows
    for d in drivers:
        d.write()
    for d, s in zip(drivers, since, strict=True):
        assert d.wait_for_update(3.0, since=s)
    for d in drivers:
        d.read()


def test_round_trip(bridge: PtyBridge, peer: ModbusPeer, clock: FakeClock) -> None:
    peer.set(1, 2, 0, [1, 0, 0, 1])
    peer.set(1, 4, 2, [4321])
    d = make(bridge, clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    d.read()  # open() waited for the first image
    assert d.inputs == {"I0": 1, "I1": 0, "I3": 1, "IR2": 4321}
    d.outputs.update({"Q1": True, "HR4": 777})
    scan(d)
    assert peer.get(1, 1, 0, 2) == [0, 1]
    assert peer.get(1, 3, 4) == [777]
    # I0, I1, I3 in one FC 2 request; IR2 one FC 4 request
    assert bridge.requests[:3] == [write_coils_request(1, 0, [0, 0]),
                                   write_registers_request(1, 4, [0]),
                                   read_request(1, 2, 0, 4)]
    assert bridge.requests[3] == read_request(1, 4, 2, 1)
    d.close()
    assert peer.get(1, 1, 0, 2) == [0, 0] and peer.get(1, 3, 4) == [0]  # safe state written
    d.close()
    assert d.health is Health.CLOSED


def test_two_units_share_one_port(bridge: PtyBridge, peer: ModbusPeer, clock: FakeClock) -> None:
    peer.set(2, 2, 0, [0, 1, 1])
    a = make(bridge, clock, unit=1, name="mb1")
    b = make(bridge, clock, unit=2, name="mb2", inputs=("I1", "I2"), outputs=("Q5",))
    a.open()
    b.open()
    assert a.line is b.line and a.line is not None
    assert [t.name for t in __import__("threading").enumerate()].count(
        f"modbus-rtu {bridge.driver_port}") == 1
    a.outputs["Q0"] = 1
    b.outputs["Q5"] = 1
    scan(a, b)
    assert b.inputs == {"I1": 1, "I2": 1}
    assert peer.get(1, 1, 0) == [1] and peer.get(2, 1, 5) == [1] and peer.get(2, 1, 0) == [0]
    a.close()
    assert shared_ports().ports()  # b still holds the port
    scan(b)
    b.close()
    assert not shared_ports().ports()


def test_exception_reply_is_a_fault_with_its_code(
    bridge: PtyBridge, peer: ModbusPeer, clock: FakeClock
) -> None:
    d = make(bridge, clock, on_fault="zero")
    d.open()
    peer.set(1, 2, 0, [1])
    scan(d)
    assert d.inputs["I0"] == 1
    peer.fail[1] = ExcCodes.DEVICE_FAILURE
    scan(d)
    assert d.health is Health.FAULT
    assert "exception 4 (server device failure)" in (d.fault_reason or "")
    assert d.inputs["I0"] == 0  # on_fault: zero
    del peer.fail[1]
    since = d.updates
    d.read()  # before the back-off delay: no retry asked
    d.write()
    assert not d.wait_for_update(0.2, since=since)
    clock.advance(d.RECONNECT_MIN_S)
    d.read()  # asks the poll thread for one attempt
    assert d.wait_for_update(3.0, since=since)
    d.read()
    assert d.health is Health.OK and d.inputs["I0"] == 1
    d.close()


def test_unknown_address_gives_illegal_data_address(
    bridge: PtyBridge, peer: ModbusPeer, clock: FakeClock
) -> None:
    d = make(bridge, clock, inputs=("I100",), outputs=())
    d.open()
    assert d.health is Health.FAULT
    assert "exception 2 (illegal data address)" in (d.fault_reason or "")
    assert "address 100" in (d.fault_reason or "")
    d.close()


def test_garbled_reply_is_retried(bridge: PtyBridge, peer: ModbusPeer, clock: FakeClock) -> None:
    d = make(bridge, clock)
    d.open()
    line = d.line
    assert line is not None
    bridge.garble_replies = 1
    peer.set(1, 2, 0, [0, 1])
    scan(d)
    assert d.health is Health.OK and d.inputs["I1"] == 1
    assert line.master.stats.crc_errors == 1 and line.master.stats.retries >= 1
    bridge.inject_to_driver(b"\x00\xff\x07")  # noise before the next reply
    peer.set(1, 2, 0, [1, 0])
    scan(d)
    assert d.health is Health.OK and d.inputs["I0"] == 1 and d.inputs["I1"] == 0
    bridge.garble_replies = 100  # a line that stays bad
    scan(d)
    assert d.health is Health.FAULT and "CRC error" in (d.fault_reason or "")
    bridge.garble_replies = 0
    d.close()


def test_cut_line_goes_stale_then_faults(bridge: PtyBridge, peer: ModbusPeer,
                                         clock: FakeClock) -> None:
    d = make(bridge, clock)
    d.open()
    scan(d)
    assert d.health is Health.OK
    bridge.cut = True
    since = d.updates
    d.write()
    clock.advance(d.stale_after_s + 0.01)  # type: ignore[operator]
    d.read()
    assert d.health is Health.STALE and not d.ok
    assert d.wait_for_update(3.0, since=since)  # timeout after the retries
    d.read()
    assert d.health is Health.FAULT and "timeout" in (d.fault_reason or "")
    bridge.cut = False
    clock.advance(d.RECONNECT_MIN_S)
    since = d.updates
    d.read()
    assert d.wait_for_update(3.0, since=since)
    d.read()
    assert d.health is Health.OK
    d.close()


def test_long_reply_on_a_slow_line_is_not_a_timeout(bridge: PtyBridge, peer: ModbusPeer,
                                                    clock: FakeClock) -> None:
    """``timeout`` is the unit's time to answer; the reply's own wire time comes on top."""
    registers = tuple(f"HR{n}" for n in range(60))  # one FC 3 request, a 125-byte reply
    peer.set(1, 3, 0, list(range(100, 160)))
    d = make(bridge, clock, inputs=registers, outputs=(), baudrate=9600, timeout="30ms",
             retries=0)
    # 125 bytes take 143 ms at 9600 baud; the bridge delivers them in about 100 ms,
    # three times the 30 ms timeout
    bridge.slow_replies = (13, 0.01)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    d.read()
    assert [d.inputs[r] for r in registers] == list(range(100, 160))
    assert d.line is not None and d.line.master.stats.timeouts == 0
    d.close()


def test_dead_unit_does_not_hold_up_its_neighbour(bridge: PtyBridge, peer: ModbusPeer,
                                                  clock: FakeClock) -> None:
    alive = make(bridge, clock, unit=1, name="alive")
    dead = make(bridge, clock, unit=9, name="dead", inputs=("I0",), outputs=())
    alive.open()
    dead.open()
    assert alive.ok and dead.health is Health.FAULT  # 1 + retries timeouts at open
    to_dead = lambda: sum(1 for r in bridge.requests if r[0] == 9)  # noqa: E731
    asked = to_dead()
    assert asked == 1 + FAST["retries"]
    peer.set(1, 2, 0, [1])
    for _ in range(5):  # no retry due: unit 9 is left out of the rounds
        dead.read()
        dead.write()
        scan(alive)
    assert to_dead() == asked and alive.inputs["I0"] == 1
    clock.advance(dead.RECONNECT_MIN_S)
    scan(alive, dead)  # the back-off attempt: one request, no retries
    assert to_dead() == asked + 1
    assert alive.health is Health.OK and dead.health is Health.FAULT
    alive.close()
    dead.close()


def test_same_port_under_two_names_is_refused(bridge: PtyBridge, peer: ModbusPeer,
                                              clock: FakeClock, tmp_path: Path) -> None:
    alias = tmp_path / "ttyRS485"
    alias.symlink_to(bridge.driver_port)
    a = make(bridge, clock, name="a")
    b = make(bridge, clock, name="b", unit=2, port=str(alias))
    a.open()
    b.open()
    assert a.ok and b.health is Health.FAULT
    assert "already opened as" in (b.fault_reason or "")
    a.close()
    b.close()


PEER_CMD = [sys.executable, os.path.join(HERE, "modbus_peer.py"), "--units", "1",
            "--set", "1:2:0:1,0,1"]


def start_peer_process(port: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen([*PEER_CMD, "--port", port], stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "ready"
    return proc


def test_server_killed_and_restarted(bridge: PtyBridge, clock: FakeClock) -> None:
    proc = start_peer_process(bridge.peer_port)
    try:
        writer = make(bridge, clock, name="mbw", inputs=(), outputs=("HR5",))
        reader = make(bridge, clock, name="mbr", inputs=("I0", "I1", "I2", "HR5"), outputs=())
        writer.open()
        reader.open()
        writer.outputs["HR5"] = 1234
        scan(writer)
        scan(reader)
        assert reader.inputs == {"I0": 1, "I1": 0, "I2": 1, "HR5": 1234}
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        scan(writer, reader)
        assert writer.health is Health.FAULT and reader.health is Health.FAULT
        assert "timeout" in (reader.fault_reason or "")
        bridge.flush_peer_side()
        proc = start_peer_process(bridge.peer_port)  # a fresh server: HR5 back to 0
        clock.advance(writer.RECONNECT_MIN_S)
        scan(writer, reader)  # the writer's retry goes first: HR5 written again
        assert writer.health is Health.OK, writer.fault_reason
        assert reader.health is Health.OK, reader.fault_reason
        scan(reader)
        assert reader.inputs == {"I0": 1, "I1": 0, "I2": 1, "HR5": 1234}
        writer.close()
        reader.close()
    finally:
        proc.kill()
        proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()


def test_poll_thread_bug_is_raised_in_the_scan(bridge: PtyBridge, peer: ModbusPeer,
                                               clock: FakeClock) -> None:
    d = make(bridge, clock)
    d.open()

    def broken(master: object, probing: bool = False) -> None:
        raise ZeroDivisionError("bug in the poll thread")

    d._exchange = broken  # type: ignore[method-assign]
    since = d.updates
    d.write()
    assert d.wait_for_update(3.0, since=since)
    with pytest.raises(ZeroDivisionError):
        d.read()
    d.close()  # still closes cleanly, thread ended
    assert not shared_ports().ports()


def test_missing_port_and_conflicting_settings(bridge: PtyBridge, peer: ModbusPeer,
                                               clock: FakeClock) -> None:
    d = ModbusRtuDriver("mb", {"port": "/dev/does-not-exist", "unit": 1}, clock=clock)
    d.add_point("I0", Direction.IN)
    d.open()
    assert d.health is Health.FAULT and "cannot open" in (d.fault_reason or "")
    d.close()
    a = make(bridge, clock, name="a")
    b = make(bridge, clock, name="b", unit=2, baudrate=9600)
    a.open()
    b.open()
    assert b.health is Health.FAULT and "9600" in (b.fault_reason or "")
    a.close()
    b.close()


@pytest.mark.parametrize("point,direction", [("I0", Direction.OUT), ("IR3", Direction.OUT),
                                             ("X1", Direction.IN), ("HR70000", Direction.IN),
                                             ("Q", Direction.OUT), ("q1", Direction.IN)])
def test_bad_points(point: str, direction: Direction) -> None:
    d = ModbusRtuDriver("mb", {"port": "/dev/ttyUSB0"})
    with pytest.raises(PointError):
        d.add_point(point, direction)


@pytest.mark.parametrize("cfg", [{}, {"port": "/dev/ttyUSB0", "unit": 0},
                                 {"port": "/dev/ttyUSB0", "parity": "X"},
                                 {"port": "/dev/ttyUSB0", "timeout": "fast"},
                                 {"port": "/dev/ttyUSB0", "retries": -1},
                                 {"port": "/dev/ttyUSB0", "stopbits": 3}])
def test_bad_config(cfg: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        ModbusRtuDriver("mb", cfg)


def test_an_inhibited_unit_is_still_polled(bridge: PtyBridge, peer: ModbusPeer,
                                           clock: FakeClock) -> None:
    """Inhibited (the watchdog's latched fault), a unit's outputs stay off, and its inputs
    are still read every scan and a cut line still seen: the poll round was started by
    ``write()`` only, which an inhibited driver skips, so the inputs went stale and the
    fault unseen (the contract suite's inhibit test passed on RTU by a race only)."""
    d = make(bridge, clock)
    d.open()
    d.inhibit(True)
    peer.set(1, 2, 0, [1])
    scan(d)  # the safe state's round
    peer.set(1, 2, 0, [0, 1])
    since = d.updates
    d.read()
    d.write()
    assert d.wait_for_update(3.0, since=since), "no poll round while inhibited"
    d.read()
    assert d.inputs["I0"] == 0 and d.inputs["I1"] == 1
    bridge.cut = True
    since = d.updates
    d.read()
    assert d.wait_for_update(3.0, since=since)
    d.read()
    assert d.health is Health.FAULT
    bridge.cut = False
    d.close()
