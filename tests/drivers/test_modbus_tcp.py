"""Modbus TCP master: MBAP frames byte by byte, then against pymodbus' TCP server, behind a
relay that refuses, resets mid-frame, delays and drops (tests/drivers/modbus_tcp_peer.py):
several units behind one gateway, exception replies, an absent unit (0x0B), a unit that
stops answering, a late reply, a peer that speaks no Modbus."""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pymodbus.constants import ExcCodes

from drivers.base import Direction, Health, PolledDriver
from drivers.config import ConfigError
from drivers.modbus_frame import (
    mbap_frame,
    mbap_header,
    read_pdu,
    write_coils_pdu,
    write_registers_pdu,
)
from drivers.modbus_tcp import Gateways, ModbusTcpDriver, shared_gateways
from tests.drivers.drvkit import FakeClock, wait_until
from tests.drivers.modbus_tcp_peer import ModbusTcpPeer, Relay, free_port

#: a reply timeout a loaded machine holds (the peer and the relay are threads of this
#: process); tests of the timeout itself set their own
FAST: dict[str, Any] = {"timeout": "300ms", "retries": 1}


def test_mbap_frames_match_the_specification() -> None:
    # Modbus Messaging on TCP/IP Implementation Guide: transaction id, protocol 0, the
    # length of unit id + PDU, unit id; then the PDU (FC 3, 10 registers from 0)
    assert mbap_frame(1, 17, read_pdu(3, 0, 10)) == bytes.fromhex("00010000000611030000000a")
    assert mbap_frame(0x1234, 255, write_registers_pdu(1, [10, 258])) == bytes.fromhex(
        "12340000000bff100001000204000a0102")
    assert mbap_header(bytes.fromhex("00070000000601")) == (7, 0, 5, 1)


@pytest.fixture
def peer() -> Iterator[ModbusTcpPeer]:
    with ModbusTcpPeer(units=(1, 2), absent=(3,)) as p:
        yield p


@pytest.fixture
def relay(peer: ModbusTcpPeer) -> Iterator[Relay]:
    r = Relay(peer.port)
    yield r
    r.close()


def make(relay: Relay, clock: FakeClock, unit: int = 1, name: str = "rio",
         inputs: tuple[str, ...] = ("I0", "I1", "I3", "IR2"),
         outputs: tuple[str, ...] = ("Q0", "Q1", "HR4"), **cfg: Any) -> ModbusTcpDriver:
    d = ModbusTcpDriver(name, {"host": "127.0.0.1", "port": relay.port, "unit": unit,
                               **FAST, **cfg}, clock=clock)
    for p in inputs:
        d.add_point(p, Direction.IN)
    for p in outputs:
        d.add_point(p, Direction.OUT)
    return d


def scan(*drivers: PolledDriver) -> None:
    """One scan as the plant does it, waiting for the poll round the write started."""
    since = [d.updates for d in drivers]
    for d in drivers:
        d.read()
    for d in drivers:
        d.write()
    for d, s in zip(drivers, since, strict=True):
        assert d.wait_for_update(3.0, since=s)
    for d in drivers:
        d.read()


def until(d: PolledDriver, cond: Callable[[], bool]) -> None:
    """Scan until ``cond`` holds (a round already under way may show older values)."""
    deadline = time.monotonic() + 5.0
    while True:
        scan(d)
        if cond():
            return
        assert time.monotonic() < deadline, "condition never met"


def recover(d: PolledDriver, clock: FakeClock) -> None:
    """Let the back-off allow a retry, and scan until the driver is OK again."""
    deadline = time.monotonic() + 5.0
    while d.health is not Health.OK:
        assert time.monotonic() < deadline, d.fault_reason
        clock.advance(d.RECONNECT_MAX_S)
        since = d.updates
        d.read()
        d.wait_for_update(1.0, since=since)
        d.read()


def test_round_trip(peer: ModbusTcpPeer, relay: Relay, clock: FakeClock) -> None:
    peer.set(1, 2, 0, [1, 0, 0, 1])
    peer.set(1, 4, 2, [4321])
    d = make(relay, clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    d.read()  # open() waited for the first image
    assert d.inputs == {"I0": 1, "I1": 0, "I3": 1, "IR2": 4321}
    d.outputs.update({"Q1": True, "HR4": 777})
    scan(d)
    assert peer.get(1, 1, 0, 2) == [0, 1] and peer.get(1, 3, 4) == [777]
    # the outputs first (Q0-Q1 in one FC 15, HR4 with FC 6), then I0, I1, I3 in one FC 2
    # request and IR2 in one FC 4 request, each behind its MBAP header
    pdus = [r[7:] for r in relay.requests]
    assert pdus[:4] == [write_coils_pdu(0, [0, 0]), write_registers_pdu(4, [0]),
                        read_pdu(2, 0, 4), read_pdu(4, 2, 1)], pdus
    assert all(r[2:4] == b"\0\0" and r[6] == 1 for r in relay.requests)
    d.close()
    assert peer.get(1, 1, 0, 2) == [0, 0] and peer.get(1, 3, 4) == [0]  # safe state
    assert not shared_gateways().keys()


def test_units_behind_one_gateway_share_its_connection(peer: ModbusTcpPeer, relay: Relay,
                                                       clock: FakeClock) -> None:
    peer.set(2, 2, 0, [0, 1, 1])
    a = make(relay, clock, unit=1, name="rio1")
    b = make(relay, clock, unit=2, name="rio2", inputs=("I1", "I2"), outputs=("Q5",))
    a.open()
    b.open()
    assert a.line is b.line and a.line is not None
    name = f"modbus-tcp 127.0.0.1:{relay.port}"
    assert [t.name for t in threading.enumerate()].count(name) == 1
    a.outputs["Q0"] = 1
    b.outputs["Q5"] = 1
    scan(a, b)
    assert b.inputs == {"I1": 1, "I2": 1}
    assert peer.get(1, 1, 0) == [1] and peer.get(2, 1, 5) == [1] and peer.get(2, 1, 0) == [0]
    assert relay.connections == 1
    a.close()
    assert shared_gateways().keys()  # b still holds the connection
    scan(b)
    b.close()
    assert not shared_gateways().keys()


def test_connection_refused_then_the_gateway_comes(peer: ModbusTcpPeer, clock: FakeClock
                                                   ) -> None:
    relay = Relay(peer.port)
    relay.refuse()
    try:
        d = make(relay, clock)
        d.open()
        assert d.health is Health.FAULT
        assert f"127.0.0.1:{relay.port}: cannot connect" in (d.fault_reason or "")
        assert "refused" in (d.fault_reason or "").lower()
        relay.listen()
        recover(d, clock)
        peer.set(1, 2, 0, [1])
        scan(d)
        assert d.inputs["I0"] == 1
        d.close()
    finally:
        relay.close()


def test_a_connection_reset_mid_frame_faults_and_reconnects(peer: ModbusTcpPeer,
                                                            relay: Relay,
                                                            clock: FakeClock) -> None:
    d = make(relay, clock, on_fault="hold")
    d.open()
    peer.set(1, 2, 0, [1])
    scan(d)
    assert d.health is Health.OK and relay.connections == 1
    relay.reset_next_reply(5)  # half an MBAP header, then RST
    d.outputs["Q0"] = 1
    scan(d)
    assert d.health is Health.FAULT
    # the frame cut short by the reset (or the reset itself, whichever the driver saw first)
    assert any(w in (d.fault_reason or "") for w in ("cut short", "reset", "closed")), \
        d.fault_reason
    assert d.inputs["I0"] == 1  # on_fault: hold
    recover(d, clock)
    assert relay.connections == 2
    scan(d)
    assert peer.get(1, 1, 0) == [1]  # the output that was cut off went out again
    d.close()


def test_exception_reply_is_a_fault_with_its_code(peer: ModbusTcpPeer, relay: Relay,
                                                  clock: FakeClock) -> None:
    d = make(relay, clock, on_fault="zero")
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
    recover(d, clock)
    assert d.inputs["I0"] == 1
    assert relay.connections == 1  # an exception is the unit's, not the connection's
    d.close()


def test_an_absent_unit_behind_the_gateway_faults_alone(peer: ModbusTcpPeer, relay: Relay,
                                                        clock: FakeClock) -> None:
    alive = make(relay, clock, unit=1, name="alive")
    absent = make(relay, clock, unit=3, name="absent", inputs=("I0",), outputs=())
    alive.open()
    absent.open()
    assert alive.ok and absent.health is Health.FAULT
    assert "exception 11 (gateway target device failed to respond)" in (
        absent.fault_reason or "")
    peer.set(1, 2, 0, [1])
    scan(alive)
    assert alive.ok and alive.inputs["I0"] == 1
    alive.close()
    absent.close()


def test_a_unit_that_stops_answering_never_holds_the_scan(peer: ModbusTcpPeer, relay: Relay,
                                                          clock: FakeClock) -> None:
    """Its requests time out in the poll thread; the scan goes on meanwhile (counted: many
    scans inside one timeout), its neighbour behind the same gateway keeps working."""
    quiet = make(relay, clock, unit=2, name="quiet", inputs=("I0",), outputs=(),
                 timeout="1s", retries=0)
    other = make(relay, clock, unit=1, name="other")
    quiet.open()
    other.open()
    assert quiet.ok and other.ok
    peer.silent.add(2)
    since = quiet.updates
    quiet.write()
    other.write()
    scans = 0
    slow = []  # scans of 0.5 s or more: a scan held for the 1 s timeout would be one
    while quiet.updates == since:
        t0 = time.monotonic()
        quiet.read()
        quiet.write()
        other.read()
        other.write()
        if (took := time.monotonic() - t0) >= 0.5:
            slow.append(took)
        scans += 1
        time.sleep(0.001)
    # a scan that waited for the reply would end the timeout in one or two scans; one
    # slow one is what a pause of this process (the machine's) can make
    assert scans >= 20 and len(slow) <= 1, (scans, slow)
    quiet.read()
    assert quiet.health is Health.FAULT and "timeout" in (quiet.fault_reason or "")
    assert relay.connections == 1  # the connection stays up for the others
    peer.set(1, 2, 1, [1])
    until(other, lambda: other.inputs["I1"] == 1)
    assert other.ok
    peer.silent.clear()
    recover(quiet, clock)
    quiet.close()
    other.close()


def test_a_late_reply_is_dropped_by_its_transaction_id(peer: ModbusTcpPeer, relay: Relay,
                                                       clock: FakeClock) -> None:
    d = make(relay, clock, inputs=("IR0",), outputs=(), timeout="300ms")
    d.open()
    assert d.line is not None
    stats = d.line.master.stats
    peer.set(1, 4, 0, [111])
    # the first reply after the 300 ms timeout, the retry's right behind it
    relay.delay_next_reply(0.45)
    scan(d)
    assert d.health is Health.OK and d.inputs["IR0"] == 111
    assert stats.timeouts == 1 and stats.late_replies == 1 and stats.retries == 1
    d.close()


def test_a_peer_that_speaks_no_modbus_is_a_fault(clock: FakeClock) -> None:
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]

    def answer() -> None:
        conn, _ = srv.accept()
        conn.recv(100)
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n")
        time.sleep(0.5)
        conn.close()
    t = threading.Thread(target=answer, daemon=True)
    t.start()
    d = ModbusTcpDriver("web", {"host": "127.0.0.1", "port": port, **FAST}, clock=clock)
    d.add_point("I0", Direction.IN)
    d.open()
    assert d.health is Health.FAULT and "not a Modbus/TCP reply" in (d.fault_reason or "")
    d.close()
    t.join(2)
    srv.close()


def test_own_gateways_open_and_close_without_leaks(peer: ModbusTcpPeer, relay: Relay,
                                                   clock: FakeClock) -> None:
    gws = Gateways()
    for _ in range(3):
        d = ModbusTcpDriver("rio", {"host": "127.0.0.1", "port": relay.port, **FAST},
                            clock=clock, gateways=gws)
        d.add_point("I0", Direction.IN)
        d.open()
        assert d.ok and gws.keys() == [f"127.0.0.1:{relay.port}"]
        assert not shared_gateways().keys()
        d.close()
        assert gws.keys() == []
    assert wait_until(lambda: relay.connections == 3)


@pytest.mark.parametrize("cfg", [{}, {"host": "127.0.0.1", "port": 0},
                                 {"host": "127.0.0.1", "unit": 256},
                                 {"host": "a b"}, {"host": "127.0.0.1", "timeout": "0s"},
                                 {"host": "127.0.0.1", "retries": 11}])
def test_bad_config(cfg: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        ModbusTcpDriver("rio", cfg)


def test_a_closed_port_is_refused_quickly(clock: FakeClock) -> None:
    d = ModbusTcpDriver("rio", {"host": "127.0.0.1", "port": free_port()}, clock=clock)
    d.add_point("I0", Direction.IN)
    t0 = time.monotonic()
    d.open()
    assert d.health is Health.FAULT and time.monotonic() - t0 < 2.0
    d.close()


def test_a_close_with_the_gateway_silent_says_the_outputs_may_be_on(
        peer: ModbusTcpPeer, relay: Relay, clock: FakeClock,
        caplog: pytest.LogCaptureFixture) -> None:
    """The safe state that no reply confirms is one error line naming the connection (the
    RTU driver's names the port: tests/daemon/test_signals.py)."""
    d = make(relay, clock)
    d.open()
    assert d.health is Health.OK, d.fault_reason
    d.outputs.update({"Q1": True})
    scan(d)
    relay.cut = True
    with caplog.at_level(logging.ERROR, logger="drivers.modbus_master"):
        d.close()
    said = [r.getMessage() for r in caplog.records if r.name == "drivers.modbus_master"]
    assert said == ["driver rio: unit 1 did not confirm the safe state before the "
                    "connection closed: its outputs may still be on"], said
    assert not shared_gateways().keys()
