"""PIN lock-out is per peer with a doubling back-off (never every console at once), and an
unlocked session locks itself again after an idle time."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from runtime.console.protocol import LOCKOUT_MAX_S, LOCKOUT_MIN_S, MAX_PIN_TRIES
from runtime.console.server import ConsoleServer
from runtime.controller.pin import hash_pin
from runtime.language.model import ConsoleEntry
from tests.console.consolekit import (
    FakeClock,
    NullModem,
    Rig,
    serial_client,
    tcp_client,
    wait_for,
)

PIN = "4711"
HASH = hash_pin(PIN, iterations=1000)


def test_wrong_pins_over_tcp_do_not_lock_the_serial_console(
        rigs: Callable[..., Rig]) -> None:
    """The attack: three wrong PINs a minute over TCP. Before: every console was locked,
    the operator at the serial line too."""
    rig = rigs(trusted=False, pin_hash=HASH)
    tcp = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    tcp.start()
    try:
        attacker = tcp_client(tcp.addresses[0])
        try:
            for _ in range(MAX_PIN_TRIES):
                attacker.error("unlock 0000")
            assert attacker.error(f"unlock {PIN}").startswith("console locked for 30 s")
        finally:
            attacker.close()
        s = rig.serial()
        assert s.ok(f"unlock {PIN}") == ["unlocked"]
        assert s.ok("pause")[0].startswith("paused")
    finally:
        tcp.stop()


def test_the_lockout_doubles_per_peer_up_to_a_cap(rigs: Callable[..., Rig]) -> None:
    clock = FakeClock()
    rig = rigs(trusted=False, pin_hash=HASH, clock=clock, serial_port=False)
    a = rig.service.session("tcp:127.0.0.1:5020", peer="tcp")
    b = rig.service.session("tcp:127.0.0.1:5020", peer="tcp")  # the same peer
    other = rig.service.session("socket:/run/c.sock", peer="uid:1000")
    assert a.feed(b"unlock 1\r") == ["error wrong PIN (2 tries left)"]
    assert b.feed(b"unlock 2\r") == ["error wrong PIN (1 try left)"]  # per peer, not session
    assert a.feed(b"unlock 3\r") == [f"error wrong PIN; locked for {LOCKOUT_MIN_S:.0f} s"]
    assert b.feed(f"unlock {PIN}\r".encode()) == [
        f"error console locked for {LOCKOUT_MIN_S:.0f} s after {MAX_PIN_TRIES} wrong PINs"]
    assert other.feed(f"unlock {PIN}\r".encode()) == ["unlocked", "ok"]
    lockout = LOCKOUT_MIN_S
    for _ in range(8):
        clock.t += lockout
        for wrong in ("1", "2"):
            a.feed(f"unlock {wrong}\r".encode())
        lockout = min(2 * lockout, LOCKOUT_MAX_S)
        assert a.feed(b"unlock 3\r") == [f"error wrong PIN; locked for {lockout:.0f} s"]
    assert lockout == LOCKOUT_MAX_S
    clock.t += lockout
    assert a.feed(f"unlock {PIN}\r".encode()) == ["unlocked", "ok"]
    # a good PIN starts the back-off again from the bottom
    for wrong in ("1", "2"):
        a.feed(f"unlock {wrong}\r".encode())
    assert a.feed(b"unlock 3\r") == [f"error wrong PIN; locked for {LOCKOUT_MIN_S:.0f} s"]


def test_an_unlocked_session_locks_itself_after_an_idle_time(
        rigs: Callable[..., Rig]) -> None:
    """The attack: unlock on the serial line and walk away; the next person on the line
    could change the machine. Now the session locks itself after relock_after_idle."""
    clock = FakeClock()
    rig = rigs(trusted=False, pin_hash=HASH, clock=clock)
    idle = rig.service.limits.relock_after_idle_s
    s = rig.serial()
    assert s.ok(f"unlock {PIN}") == ["unlocked"]
    clock.t += idle - 1
    s.ok("force t1.iMarcha 1")  # input restarts the idle time
    clock.t += idle - 1
    assert s.ok("status")[0] == "state running"
    clock.t += idle
    assert s.line() == f"locked after {idle:.0f} s idle: 'unlock PIN' to change the machine"
    assert s.error("pause") == "locked: 'unlock PIN' first"
    assert list(rig.plant.forced) == ["t1.iMarcha"]  # its force keeps its own time limit
    # a fresh session is always locked
    assert rig.connect().error("pause") == "locked: 'unlock PIN' first"


def test_the_next_person_after_a_serial_hang_up_needs_the_pin(
        rigs: Callable[..., Rig]) -> None:
    """A hang-up ends the session; the port opened again starts a fresh, locked one."""
    rig = rigs(trusted=False, pin_hash=HASH, serial_port=False)
    link = Path(rig.tmp, "ttyGS0")
    first, second = NullModem(), NullModem()
    server = ConsoleServer(rig.service, [ConsoleEntry("serial", str(link))])
    link.symlink_to(first.daemon_port)
    server.start()
    try:
        wait_for(lambda: server.sessions, "the serial port opened")
        a = serial_client(first.peer_port)
        assert a.ok(f"unlock {PIN}") == ["unlocked"]
        a.close()
        first.hangup()
        wait_for(lambda: not server.sessions, "the hang-up seen")
        link.unlink()
        link.symlink_to(second.daemon_port)
        wait_for(lambda: server.sessions, "the port opened again")
        b = serial_client(second.peer_port)
        assert b.error("pause") == "locked: 'unlock PIN' first"
        b.close()
    finally:
        server.stop()
        first.close()
        second.close()
