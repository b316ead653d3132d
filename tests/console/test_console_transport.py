"""Transport limits over real sockets and a real pty: a bounded number of sessions per
socket that idle connections cannot keep (an empty line is not activity), idle
unauthenticated connections closed, lines over a session's rate answered with an error,
and a serial line's hang-up ending its session so that the next person on the line finds
it locked."""

from __future__ import annotations

import array
import fcntl
import logging
import math
import os
import select
import termios
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from runtime.console.server import (
    BURST_LINES,
    EVICT_IDLE_S,
    IDLE_TIMEOUT_S,
    MAX_CONNECTIONS,
    ConsoleServer,
)
from runtime.controller.pin import hash_pin
from runtime.language.model import ConsoleEntry
from tests.console.consolekit import (
    FakeClock,
    LineClient,
    Rig,
    tcp_client,
    wait_for,
)

PIN = "4711"
HASH = hash_pin(PIN, iterations=1000)


@pytest.fixture
def tcp(rigs: Callable[..., Rig]) -> Iterator[tuple[Rig, ConsoleServer, FakeClock]]:
    """A rig whose console clock the test steps, with an untrusted TCP console (PIN
    4711) beside its trusted serial line and socket."""
    clock = FakeClock()
    rig = rigs(pin_hash=HASH, clock=clock)
    server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    server.start()
    yield rig, server, clock
    server.stop()


def tcp_sessions(server: ConsoleServer) -> int:
    return len([s for s in server.sessions if s.name.startswith("tcp")])


def connect(rig: Rig, server: ConsoleServer) -> LineClient:
    c = tcp_client(server.addresses[0])
    rig.clients.append(c)
    return c


def all_read(server: ConsoleServer) -> bool:
    """Every byte the TCP clients sent has been read and handled by the server."""
    for c in list(server._conns):
        unread = array.array("i", [0])
        fcntl.ioctl(c.sock.fileno(), termios.FIONREAD, unread)
        if unread[0] or c.line.inbuf:
            return False
    return True


#: what a client may send to look alive without giving a command: an empty line (CR LF,
#: LF, CR), spaces, Ctrl-C
KEEP_ALIVES = (b"\r\n", b"\n", b"\r", b"   \r\n", b"\x03")


def test_idle_connections_do_not_lock_the_operator_out(
        tcp: tuple[Rig, ConsoleServer, FakeClock]) -> None:
    """Eight connections that say nothing take every place; a ninth is refused with an
    error line while they are fresh, and gets in once one of them has been idle
    EVICT_IDLE_S: the one idle longest is told why and closed. The serial console is
    never counted."""
    rig, server, clock = tcp
    idle = []
    for _ in range(MAX_CONNECTIONS):
        idle.append(connect(rig, server))
        # accepted at this clock time (one second apart: the first is idle longest)
        wait_for(lambda: tcp_sessions(server) == len(idle), "the connection accepted")
        clock.t += 1.0
    refused = connect(rig, server)
    assert refused.line() == f"error too many console sessions ({MAX_CONNECTIONS})"
    with pytest.raises(EOFError):
        refused.line()
    assert rig.serial().ok("get t1.iMarcha") == ["t1.iMarcha=0"]  # serial: its own place
    clock.t += EVICT_IDLE_S  # all of them idle long enough now: the oldest makes room
    operator = connect(rig, server)
    assert operator.cmd("status")[0] == "state running"
    assert idle[0].line().startswith("error idle timeout")
    with pytest.raises(EOFError):
        idle[0].line()
    assert idle[1].cmd("status")[-1] == "ok"  # the others are still served
    assert tcp_sessions(server) == MAX_CONNECTIONS


def test_empty_lines_do_not_keep_a_place(
        tcp: tuple[Rig, ConsoleServer, FakeClock]) -> None:
    """The attack: eight TCP connections that each send an empty line every 4 s kept
    every place for good (the idle time counted from any byte). Only a command (a line
    that gets a reply) is activity: empty lines, spaces and Ctrl-C are not, so after
    EVICT_IDLE_S the operator gets in, and after IDLE_TIMEOUT_S each is closed. A
    connection that sends a command keeps its place."""
    rig, server, clock = tcp
    squatters = []
    for _ in range(MAX_CONNECTIONS):
        squatters.append(connect(rig, server))
        wait_for(lambda: tcp_sessions(server) == len(squatters), "the connection accepted")
    for k in range(4):  # 16 s of keep-alives, every 4 s
        clock.t += 4.0
        for c in squatters:
            c.send(KEEP_ALIVES[k % len(KEEP_ALIVES)])
        wait_for(lambda: all_read(server), "the keep-alives read")
    assert all(c.pending() == b"" for c in squatters)  # no reply to any of them
    operator = connect(rig, server)
    assert operator.cmd("status")[0] == "state running"
    assert squatters[0].line().startswith("error idle timeout (16 s without input")
    # the others, still sending keep-alives, are closed after IDLE_TIMEOUT_S; the
    # operator, sending a command every 4 s, is not
    others = squatters[1:]
    for k in range(int((IDLE_TIMEOUT_S - 16.0) // 4.0) + 1):
        clock.t += 4.0
        for c in others:
            c.send(KEEP_ALIVES[k % len(KEEP_ALIVES)])
        wait_for(lambda: all_read(server), "the keep-alives read")
        assert operator.cmd("help stats")[-1] == "ok"
    for c in others:
        assert c.line().startswith("error idle timeout")
        with pytest.raises(EOFError):
            c.line()
    wait_for(lambda: tcp_sessions(server) == 1, "the idle sessions closed")


def test_empty_lines_do_not_keep_a_session_unlocked(
        tcp: tuple[Rig, ConsoleServer, FakeClock]) -> None:
    """An unlocked session whose client sends only keep-alives locks itself after
    relock_after_idle, as one that sends nothing."""
    rig, server, clock = tcp
    idle = rig.service.limits.relock_after_idle_s
    c = connect(rig, server)
    assert c.ok(f"unlock {PIN}") == ["unlocked"]
    (session,) = [s for s in server.sessions if s.name.startswith("tcp")]
    for k in range(math.ceil(idle / 4.0) - 1):  # up to just before relock_after_idle
        clock.t += 4.0
        c.send(KEEP_ALIVES[k % len(KEEP_ALIVES)])
        wait_for(lambda: all_read(server), "the keep-alives read")
        # the server looked at it at this time (it polls sessions in real time, 20 times
        # a second; the test's clock jumps)
        wait_for(lambda: server.idle_s(session) == 0.0, "the server to see it unlocked")
    clock.t += 4.0
    assert c.line() == f"locked after {idle:.0f} s idle: 'unlock PIN' to change the machine"
    assert c.error("pause") == "locked: 'unlock PIN' first"


def test_an_idle_unauthenticated_connection_is_closed(
        tcp: tuple[Rig, ConsoleServer, FakeClock]) -> None:
    """IDLE_TIMEOUT_S without input closes a connection neither trusted nor unlocked,
    with an error line; an unlocked one and a trusted one stay."""
    rig, server, clock = tcp
    idle, unlocked, trusted = connect(rig, server), connect(rig, server), rig.connect()
    assert unlocked.ok(f"unlock {PIN}")
    assert idle.cmd("status")[-1] == "ok" and trusted.cmd("status")[-1] == "ok"
    clock.t += IDLE_TIMEOUT_S - 1.0
    assert idle.cmd("status")[-1] == "ok"  # input: the idle time starts again
    clock.t += IDLE_TIMEOUT_S - 1.0
    assert idle.pending(0.3) == b""  # not idle long enough yet
    clock.t += 2.0
    assert idle.line().startswith("error idle timeout (61 s without input")
    with pytest.raises(EOFError):
        idle.line()
    wait_for(lambda: tcp_sessions(server) == 1, "the idle session closed")
    assert unlocked.cmd("status")[-1] == "ok" and trusted.cmd("status")[-1] == "ok"
    # locked again without a line of its own (the relock after an idle time): its idle
    # time counts from then, not from its last input long ago
    clock.t += 3 * IDLE_TIMEOUT_S
    (session,) = [s for s in server.sessions if s.name.startswith("tcp")]
    wait_for(lambda: server.idle_s(session) == 0.0, "the server to see it unlocked")
    session.unlocked = False
    clock.t += IDLE_TIMEOUT_S - 1.0
    assert unlocked.pending(0.3) == b""
    clock.t += 2.0
    assert unlocked.line().startswith("error idle timeout")


def test_lines_over_the_rate_get_an_error_reply(
        tcp: tuple[Rig, ConsoleServer, FakeClock]) -> None:
    """A burst of pipelined lines: the first BURST_LINES run, the others are each answered
    ``error too many requests`` (never silence), in order, and the session goes on."""
    rig, server, _ = tcp
    c = connect(rig, server)
    n = 3 * BURST_LINES
    # a command answered without the scan thread: a line that waits for a scan boundary
    # (``get``) is handled about once a cycle, as slowly as the rate on a busy machine
    c.send(b"help stats\r\n" * n)
    replies = [c.reply(timeout=30) for _ in range(n)]
    finals = [r[-1] for r in replies]
    ok = finals.count("ok")
    refused = [f for f in finals if f.startswith("error too many requests")]
    assert ok + len(refused) == n, set(finals)
    assert ok >= BURST_LINES and refused, (ok, len(refused))
    assert finals[:BURST_LINES] == ["ok"] * BURST_LINES
    wait_for(lambda: c.cmd("get t1.iMarcha")[-1] == "ok", "a token again")


@pytest.fixture
def pty_line(tmp_path: Path) -> Iterator[Callable[[], tuple[int, str]]]:
    """New pty pairs: the test holds the master (the far end of the line) and points
    ``tmp_path/ttyS0`` at the slave, as a serial port that comes and goes."""
    masters: list[int] = []
    link = tmp_path / "ttyS0"

    def plug() -> tuple[int, str]:
        master, slave = os.openpty()
        tty.setraw(slave)
        name = os.ttyname(slave)
        os.close(slave)
        if link.is_symlink():
            link.unlink()
        link.symlink_to(name)
        masters.append(master)
        return master, str(link)
    yield plug
    for fd in masters:
        try:
            os.close(fd)
        except OSError:
            pass


def test_a_hang_up_locks_the_serial_console_again(
        rigs: Callable[..., Rig], pty_line: Callable[[], tuple[int, str]],
        caplog: pytest.LogCaptureFixture) -> None:
    """Unlock on a serial line, hang it up (the far end's pty master closed: POLLHUP on
    the port), bring the line back: the next person finds a new, locked session."""
    master, path = pty_line()
    rig = rigs(serial_port=False, unix_socket=False, trusted=False, pin_hash=HASH,
               serial_path=path)
    wait_for(lambda: rig.server.sessions, "the serial console to open")
    first = rig.server.sessions[0]
    line = LineClient(lambda b: os.write(master, b), _reader(master), lambda: None)
    assert line.ok(f"unlock {PIN}") and first.unlocked
    caplog.set_level(logging.INFO, logger="runtime.console.server")
    os.close(master)  # hang-up
    wait_for(lambda: first not in rig.server.sessions, "the hang-up seen")
    assert any("hang-up" in r.getMessage() for r in caplog.records)
    master, _ = pty_line()
    wait_for(lambda: rig.server.sessions, "the line served again")
    line = LineClient(lambda b: os.write(master, b), _reader(master), lambda: None)
    assert line.error("pause") == "locked: 'unlock PIN' first"
    (second,) = rig.server.sessions
    assert second is not first and not second.unlocked


def _reader(fd: int) -> Callable[[float], bytes | None]:
    def recv(timeout: float) -> bytes | None:
        ready, _, _ = select.select([fd], [], [], timeout)
        return os.read(fd, 65536) if ready else b""
    return recv


def test_carrier_lost_locks_the_serial_console_again(
        rigs: Callable[..., Rig], pty_line: Callable[[], tuple[int, str]],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A port with modem lines: the carrier detect line drops (the modem or the terminal
    at the far end hung up) while the fd stays open. A pty has no modem lines, so the
    port's ``cd`` is the one thing played here; the bytes go over the real pty."""
    import serial

    carrier = {"cd": True}
    monkeypatch.setattr(serial.Serial, "cd", property(lambda self: carrier["cd"]))
    master, path = pty_line()
    rig = rigs(serial_port=False, unix_socket=False, trusted=False, pin_hash=HASH,
               serial_path=path)
    wait_for(lambda: rig.server.sessions, "the serial console to open")
    first = rig.server.sessions[0]
    line = LineClient(lambda b: os.write(master, b), _reader(master), lambda: None)
    assert line.ok(f"unlock {PIN}") and first.unlocked
    carrier["cd"] = False
    wait_for(lambda: first not in rig.server.sessions, "the carrier loss seen")
    wait_for(lambda: rig.server.sessions, "the port opened again")
    carrier["cd"] = True
    assert line.error("pause") == "locked: 'unlock PIN' first"
    (second,) = rig.server.sessions
    assert second is not first and not second.unlocked
