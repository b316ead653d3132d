"""Several sessions at once (serial + socket + TCP), forces released with their session,
and the shipped drawer tester plant driven end to end as a person at picocom would."""

from __future__ import annotations

import json
import re
import socket
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from runtime.console.server import MAX_CONNECTIONS, ConsoleServer
from runtime.console.service import ConsoleService
from runtime.controller.daemon import Daemon
from runtime.language.model import ConsoleEntry
from runtime.language.plantfile import load_plant
from tests.console.consolekit import ROOT, NullModem, Rig, serial_client, tcp_client, wait_for


def socket_sessions(rig: Rig) -> list[object]:
    return [x for x in rig.server.sessions if x.name.startswith("socket")]


def test_serial_and_socket_sessions_at_once(rig: Rig) -> None:
    ser, sock = rig.serial(), rig.connect()
    ser.ok("watch t1.iMarcha")
    assert ser.line() == "watch: t1.iMarcha=0"
    # the socket session works while the serial one streams, and its changes show there
    sock.ok("force t1.iMarcha 1")
    assert "t1.iMarcha=1" in ser.until(lambda x: "t1.iMarcha=1" in x)[-1]
    assert sock.ok("get t1.iMarcha") == ["t1.iMarcha=1 (forced)"]
    ser.send(b"\r")
    assert "forced t1.iMarcha=1" in ser.ok("status")
    # each session has its own mode
    sock.cmd("json on")
    assert json.loads(sock.cmd("status")[0])["forced"] == {"t1.iMarcha": 1}
    assert ser.ok("get t1.iMarcha") == ["t1.iMarcha=1 (forced)"]
    # one session steps, the other sees it stepping
    ser.ok("pause")
    ser.send(b"cycle 150\r\n")
    wait_for(lambda: json.loads(sock.cmd("status")[0])["state"] == "stepping", "stepping")
    out = ser.reply(timeout=30)
    assert out[0].startswith("ran 150 scan(s)") and out[-1] == "ok"
    assert json.loads(sock.cmd("status")[0])["state"] == "paused"
    assert json.loads(sock.cmd("cycle")[0])["text"][0].startswith("ran 1 scan(s)")


def test_a_forced_name_is_released_when_its_session_ends(rigs: Callable[..., Rig]) -> None:
    rig = rigs(release=True)
    keeper, leaver = rig.connect(), rig.connect()
    keeper.ok("force t2.iMarcha 1")
    leaver.ok("force t1.iMarcha 1")
    leaver.ok("force rio.Q2 0")
    leaver.close()
    wait_for(lambda: "t1.iMarcha" not in rig.plant.forced, "t1.iMarcha released")
    assert "rio.Q2" not in rig.plant.forced_points
    assert list(rig.plant.forced) == ["t2.iMarcha"]  # another session's force stays


def test_without_release_forces_go_and_the_controller_halts(rig: Rig) -> None:
    """(Changed: the forces of a session that ended used to stay, with nobody watching;
    test_console_ownership.py has the rest.)"""
    c = rig.connect()
    c.ok("force t1.iMarcha 1")
    c.close()
    wait_for(lambda: not socket_sessions(rig), "the session to end")
    assert not rig.plant.forced
    assert rig.connect().ok("status")[0].startswith("state halted (console socket:")


def test_lock_releases_every_force_of_every_session(rig: Rig) -> None:
    a, b = rig.serial(), rig.connect()
    a.ok("force t1.iMarcha 1")
    b.ok("force t2.iMarcha 1")
    assert b.ok("lock")[0].startswith("locked; released t1.iMarcha, t2.iMarcha")
    assert not rig.plant.forced


def test_too_many_sessions_are_refused(rig: Rig) -> None:
    clients = [rig.connect() for _ in range(MAX_CONNECTIONS)]
    for c in clients:
        assert c.cmd("status")[-1] == "ok"
    extra = rig.connect()
    assert extra.line() == f"error too many console sessions ({MAX_CONNECTIONS})"
    clients[0].close()
    wait_for(lambda: len(socket_sessions(rig)) < MAX_CONNECTIONS, "a free place")
    assert rig.connect().cmd("status")[-1] == "ok"


@pytest.fixture
def shipped(tmp_path: Path) -> Iterator[tuple[Daemon, ConsoleServer, NullModem]]:
    """configs/drawer_tester/plant_sim.yaml as shipped, its console moved to a pty and a
    TCP port, its retained data to tmp_path (the socket and retain file of a real run in
    /tmp/softplc are left alone)."""
    pdef = load_plant(str(ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"))
    assert [c.kind for c in pdef.consoles] == ["socket"] and pdef.consoles[0].trusted
    modem = NullModem()
    pdef.consoles = [ConsoleEntry("serial", modem.daemon_port, 115200, trusted=True),
                     ConsoleEntry("tcp", "127.0.0.1:0", trusted=False)]
    pdef.retain_path = str(tmp_path / "retain.json")
    daemon = Daemon(pdef, sim=True, manage_gc=False)
    daemon.start()
    server = ConsoleServer(ConsoleService(daemon, pdef.pin_hash), pdef.consoles)
    server.start()
    yield daemon, server, modem
    server.stop()
    daemon.stop("end of test")
    modem.close()


def test_the_drawer_tester_at_picocom(
        shipped: tuple[Daemon, ConsoleServer, NullModem]) -> None:
    """Watch, pause, step, force and explain the shipped plant on simulated I/O."""
    daemon, server, modem = shipped
    wait_for(lambda: server.sessions, "the serial console")
    s = serial_client(modem.peer_port)
    try:
        assert s.ok("status")[2:] == ["tester1: gsParado", "tester2: gsParado"]
        s.ok("set sim.I0 1")  # NC stop buttons released
        s.ok("set sim.I4 1")
        s.ok("watch tester1.gsAbrir.X sim.Q0")
        s.line()
        s.send(b"set sim.I1 1\r\n")
        # the set ended the watch; its reply follows
        assert s.until(lambda x: x == "ok")[-2] == "sim.I1 set to 1"
        s.ok("pause")
        s.ok("force tester1.iAbierto 1")
        assert re.match(r"scan \d+: tester1 gsAbrir -> gsCerrar; ", s.ok("cycle")[1])
        why = s.ok("why tester1")
        assert why[0].startswith("gsCerrar active for")
        assert "  [false] gsCerrar -> gsParado when tParo" in why
        s.ok("unforce all")
        s.ok("resume")
        assert s.ok("status")[0] == "state running"
        # the TCP console of the same plant: not trusted and no PIN: read-only
        tcp = tcp_client(server.addresses[-1])
        try:
            assert tcp.cmd("status")[-1] == "ok"
            assert tcp.error("pause").startswith("changing commands are disabled")
        finally:
            tcp.close()
    finally:
        s.close()


def test_tcp_binds_to_localhost_only(rig: Rig) -> None:
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "0.0.0.0:0")])
    with pytest.raises(ValueError, match="127.0.0.1 only"):
        server.start()
    server.stop()
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    server.start()
    try:
        host, port = server.addresses[0].rsplit(":", 1)
        assert host == "127.0.0.1"
        with socket.create_connection((host, int(port))) as c:
            c.sendall(b"status\n")
            assert c.recv(100).startswith(b"state running")
    finally:
        server.stop()


def test_a_serial_port_that_comes_back_is_served_again(rig: Rig) -> None:
    """A port missing at start-up (a USB gadget not plugged in yet) is tried again, and so
    is a port that hung up: the console comes back with the cable."""
    link = Path(rig.tmp, "ttyGS0")
    first, second = NullModem(), NullModem()
    server = ConsoleServer(rig.service, [ConsoleEntry("serial", str(link), trusted=True)])
    server.start()
    try:
        link.symlink_to(first.daemon_port)
        wait_for(lambda: server.sessions, "the port opened once it exists")
        a = serial_client(first.peer_port)
        assert a.cmd("status")[-1] == "ok"
        a.close()
        first.hangup()
        wait_for(lambda: not server.sessions, "the hang-up seen")
        link.unlink()
        link.symlink_to(second.daemon_port)
        wait_for(lambda: server.sessions, "the port opened again")
        b = serial_client(second.peer_port)
        assert b.cmd("status")[-1] == "ok"
        b.close()
    finally:
        server.stop()
        first.close()
        second.close()
