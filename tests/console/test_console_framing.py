"""Line framing over a real pty: terminators, long lines, bad bytes, editing keys,
disconnects in mid-line. Every bad line gets an error and changes nothing."""

from __future__ import annotations

from collections.abc import Callable

from runtime.console.protocol import MAX_LINE, PARTIAL_LINE_TIMEOUT_S
from tests.console.consolekit import FakeClock, Rig, wait_for


def test_cr_lf_and_crlf_each_end_a_line(rig: Rig) -> None:
    s = rig.serial()
    for end in (b"\r", b"\n", b"\r\n"):
        out = s.cmd("status", end)
        assert out[0] == "state running" and out[-1] == "ok"
    # a CRLF split across two writes is one terminator, not a second (empty) line: the
    # LF must not stop the watch that the CR started
    s.send(b"watch t1.iMarcha\r")
    assert s.reply()[-1] == "ok"
    assert s.line().startswith("watch")
    s.send(b"\n")
    rig.set_input("I1", 1)
    assert "t1.iMarcha=1" in s.until(lambda x: "t1.iMarcha=1" in x)[-1]
    s.send(b"\r\n")  # an empty line stops the stream, and gets no reply
    out = s.cmd("help status")
    assert out == ["status   " + out[0][9:], "ok"] and out[0].startswith("status")


def test_empty_lines_get_no_reply(rig: Rig) -> None:
    s = rig.serial()
    s.send(b"\r\n\r\n   \r\n")
    assert s.cmd("status")[0] == "state running"  # the first reply is status's


def test_a_2000_byte_line_is_refused_and_changes_nothing(rig: Rig) -> None:
    s = rig.serial()
    line = b"force t1.iMarcha 1" + b" " * (2000 - 18)
    assert len(line) == 2000
    assert s.error(line) == f"line longer than {MAX_LINE} bytes: ignored"
    assert not rig.plant.forced
    # sent in pieces, the same
    s.send(line[:700])
    s.send(line[700:1400])
    assert s.error(line[1400:]).startswith("line longer")
    assert not rig.plant.forced
    # the limit itself is accepted
    assert s.cmd(b"status" + b" " * (MAX_LINE - 6))[-1] == "ok"
    assert s.error(b"status" + b" " * (MAX_LINE - 5)).startswith("line longer")


def test_invalid_utf8_is_refused_and_changes_nothing(rig: Rig) -> None:
    s = rig.serial()
    assert s.error(b"force t1.iMarcha 1 \xff\xfe") == "line is not valid UTF-8: ignored"
    assert s.error(b"\xc3") == "line is not valid UTF-8: ignored"  # a cut sequence
    assert not rig.plant.forced
    assert s.ok("get t1.iMarcha") == ["t1.iMarcha=0"]


def test_control_characters_are_refused_and_never_echoed(rig: Rig) -> None:
    s = rig.serial()
    reason = s.error(b"status\x1b[A")  # an arrow key typed at picocom
    assert reason.startswith("control character '\\x1b'")
    reason = s.error(b"\x1b[2Jfoo")
    assert "\x1b" not in reason
    out = s.cmd(b"fo\x1bo")
    assert "\x1b" not in out[-1]


def test_unknown_commands(rig: Rig) -> None:
    s = rig.serial()
    assert s.error("foo") == "unknown command 'foo' (try help)"
    assert s.error("hlep") == "unknown command 'hlep' (try help) (did you mean 'help'?)"
    assert s.error("x" * 300) == f"unknown command '{'x' * 40}...' (try help)"  # cut
    assert s.cmd("STATUS")[-1] == "ok"  # commands are not case-sensitive


def test_backspace_and_ctrl_u_edit_the_line(rig: Rig) -> None:
    s = rig.serial()
    assert s.cmd(b"statuz\x7fs")[0] == "state running"
    assert s.error(b"stat\b\bat\bt\bus").startswith("unknown command 'staus'")
    assert s.cmd(b"force t1.iMarcha 1\x15status")[0] == "state running"
    assert not rig.plant.forced


def test_ctrl_c_drops_the_half_line_and_stops_a_stream(rig: Rig) -> None:
    s = rig.serial()
    s.send(b"force t1.iMarcha 1\x03")
    assert s.cmd("get t1.iMarcha") == ["t1.iMarcha=0", "ok"]  # no reply to the dropped line
    assert not rig.plant.forced
    s.send(b"watch rio.I1\r\n")
    assert s.reply()[-1] == "ok"
    s.line()
    s.send(b"\x03status\r\n")
    lines = s.until(lambda x: x == "ok")
    assert "state running" in lines
    (session,) = rig.server.sessions
    assert session.stream is None and rig.service.tap.streams == ()
    assert rig.service.tap.on_scan not in rig.daemon._listeners


def test_a_half_line_is_dropped_after_its_timeout(rigs: Callable[..., Rig]) -> None:
    clock = FakeClock()
    rig = rigs(clock=clock)
    s = rig.serial()
    s.send(b"force t1.iMarcha 1")
    wait_for(lambda: any(x._buf for x in rig.server.sessions), "the half line")
    clock.t += PARTIAL_LINE_TIMEOUT_S + 1
    assert s.cmd(b"status")[0] == "state running"  # not 'force ... 1status'
    assert not rig.plant.forced
    # a half line younger than the timeout is kept
    s.send(b"get t1.")
    wait_for(lambda: any(x._buf for x in rig.server.sessions), "the half line")
    clock.t += PARTIAL_LINE_TIMEOUT_S - 1
    assert s.cmd(b"iMarcha") == ["t1.iMarcha=0", "ok"]


def test_socket_disconnect_in_mid_line_changes_nothing(rig: Rig) -> None:
    c = rig.connect()
    c.send(b"force t1.iMarcha 1")
    wait_for(lambda: any(x._buf for x in rig.server.sessions), "the half line")
    c.close()
    wait_for(lambda: not rig.server.sessions or all(
        not x.name.startswith("socket") for x in rig.server.sessions), "the session to end")
    assert not rig.plant.forced
    assert rig.state() == "running"
    assert rig.connect().cmd("status")[-1] == "ok"


def test_serial_hangup_in_mid_line_ends_the_session(rigs: Callable[..., Rig]) -> None:
    rig = rigs(release=True)
    s = rig.serial()
    s.ok("force t1.iAbierto 1")
    s.send(b"force t1.iMarcha 1")  # half a line, then the cable is pulled
    wait_for(lambda: any(x._buf for x in rig.server.sessions), "the half line")
    assert rig.modem is not None
    rig.modem.hangup()
    wait_for(lambda: not any(x.name.startswith("serial") for x in rig.server.sessions),
             "the serial session to end")
    assert not rig.plant.forced  # the half line never ran; the session's force released
    assert rig.state() == "running"
    assert rig.connect().cmd("status")[-1] == "ok"
