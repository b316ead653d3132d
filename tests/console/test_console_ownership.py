"""Pause, stepping, iocheck and forces belong to the session that made them: when it ends
the controller halts with every output off until ``ack``; a pause and a force last at most
the plant's limits (a warning first); ``ack`` leaves no force behind."""

from __future__ import annotations

import json
import re
import socket
import struct
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.errors import SourceError
from runtime.language.model import ConsoleLimits
from runtime.language.plantfile import load_plant
from tests.console.consolekit import FakeClock, LineClient, Rig, wait_for


def outputs(rig: Rig) -> dict[str, int]:
    return dict(rig.daemon.call(lambda: dict(rig.driver.outputs)))


def halted_reason(rig: Rig) -> str:
    st = rig.daemon.status()
    assert st["state"] == "halted", st
    return str(st["fault"])


def test_a_session_that_forced_an_output_and_left_halts_the_controller(rig: Rig) -> None:
    """The attack: force an output, drop the connection. Before: the output stayed on and
    the stop button did nothing, for as long as anyone cared to wait."""
    c = rig.connect()
    c.ok("force rio.Q0 1")
    wait_for(lambda: outputs(rig)["Q0"] == 1, "rio.Q0 forced on")
    c.close()
    wait_for(lambda: rig.state() == "halted", "the controller halted by the session's end")
    reason = halted_reason(rig)
    assert re.fullmatch(r"console socket:\S+ ended \(.+\) while it held: force rio\.Q0; "
                        r"'ack' restarts the charts from their initial situation", reason)
    assert not rig.plant.forced_points
    # outputs off, and they stay off: the stop button is no longer needed to get there
    scans = rig.daemon.scan_stats.count
    wait_for(lambda: rig.daemon.scan_stats.count > scans + 3, "a few cycles")
    assert set(outputs(rig).values()) == {0}
    other = rig.serial()
    assert other.ok("ack") == ["charts restarted from their initial situation"]
    wait_for(lambda: outputs(rig)["Q2"] == 1, "pilot 'stopped' on: the charts run again")
    assert outputs(rig)["Q0"] == 0


def test_a_session_that_paused_and_left_halts_instead_of_freezing(rig: Rig) -> None:
    rig.set_input("I1", 1)
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 opening the drawer")
    c = rig.connect()
    c.ok("pause")
    c.ok("force t2.iMarcha 1")
    assert outputs(rig)["Q0"] == 1  # paused with the drawer motor on
    c.close()
    wait_for(lambda: rig.state() == "halted", "the controller halted")
    assert "while it held: pause, force t2.iMarcha;" in halted_reason(rig)
    assert set(outputs(rig).values()) == {0} and not rig.plant.forced
    assert not rig.plant.held  # the pause is over: ack restarts the charts, running
    rig.serial().ok("ack")
    assert rig.state() == "running"


def test_a_session_in_iocheck_that_left_halts(rig: Rig) -> None:
    c = rig.connect()
    c.ok("iocheck on")
    c.ok("set rio.Q3 1")
    wait_for(lambda: outputs(rig)["Q3"] == 1, "rio.Q3 on")
    c.close()
    wait_for(lambda: rig.state() == "halted", "the controller halted")
    assert "while it held: iocheck;" in halted_reason(rig)
    assert not rig.plant.iocheck and set(outputs(rig).values()) == {0}


def test_a_session_closed_while_stepping_cancels_the_steps_and_halts(rig: Rig) -> None:
    """A session that ends while its ``cycle`` runs gets no reply: the stepping is
    cancelled and the controller halted; nothing of the command is left listening."""
    s = rig.service.session("tcp:test", trusted=True, peer="tcp")
    s.feed(b"pause\r\n")
    listeners = len(rig.daemon._listeners)
    assert s.feed(b"cycle 10000\r\n") == [] and s.pending is not None
    assert s.feed(b"status\r\n") == ["error 'cycle' is still running: its reply comes "
                                      "first (Ctrl-C stops it)"]
    wait_for(lambda: rig.state() == "stepping", "stepping")
    s.close("peer disconnected")
    assert s.pending is None and len(rig.daemon._listeners) == listeners
    assert rig.state() == "halted" and not rig.plant.stepping
    assert "ended (peer disconnected) while it held: pause, cycle;" in halted_reason(rig)


#: how soon the end of a session holding the stepping must be seen: a failure deadline,
#: far above what it takes (a poll of the server and a scan boundary, tens of ms) and far
#: below what it took while ``cycle`` blocked the sockets' thread (until the scans ran,
#: 100 s); above a pause of this process or of the machine (CI saw 0.8 s)
NOTICED_WITHIN_S = 5.0


def reset(c: LineClient) -> None:
    """Drop the connection with a TCP-style reset (SO_LINGER 0): no goodbye."""
    sock = c._close.__self__  # type: ignore[attr-defined]
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    c.close()


def test_a_long_cycle_blocks_no_other_console_and_its_end_is_seen_at_once(
        rig: Rig) -> None:
    """The attack: one session's ``cycle 10000`` (100 s at 10 ms) froze every socket
    console until the scans had run, and a reset of that connection was seen only then.
    Now the other sessions keep answering while it steps, and its end halts the
    controller (outputs off) as promptly as any other session's end."""
    stepper, other = rig.connect(), rig.connect()
    stepper.ok("pause")
    stepper.send(b"cycle 10000\r\n")
    wait_for(lambda: rig.state() == "stepping", "stepping")
    assert other.cmd("status")[0] == "state stepping"  # the same thread serves both
    assert other.ok("get t1.iMarcha") == ["t1.iMarcha=0"]
    assert stepper.pending(0.2) == b""  # its reply waits for its scans
    reset(stepper)
    t0 = time.monotonic()
    wait_for(lambda: rig.state() == "halted", "the halt", timeout=NOTICED_WITHIN_S)
    took = time.monotonic() - t0
    assert "ended (peer disconnected) while it held: pause, cycle;" in halted_reason(rig)
    assert not rig.plant.stepping and set(outputs(rig).values()) == {0}, took
    assert other.ok("ack") == ["charts restarted from their initial situation"]


def test_ctrl_c_stops_a_running_cycle(rig: Rig) -> None:
    """Ctrl-C stops a ``cycle N`` on its way: the reply says how many scans ran and what
    they changed; the controller stays paused, held by that session."""
    c = rig.connect()
    c.ok("pause")
    c.send(b"cycle 10000\r\nstatus\r\n")
    wait_for(lambda: rig.state() == "stepping", "stepping")
    c.send(b"\x03")
    out = c.reply()
    assert re.fullmatch(r"error cycle stopped by Ctrl-C after \d+ of 10000 scans",
                        out[-1]), out
    assert re.fullmatch(r"ran \d+ of 10000 scan\(s\) \(\d+\.\.\d+\)", out[0]), out
    assert c.reply()[0] == "state paused"  # the line sent after it, answered after it
    assert rig.service.holdings() == ["pause"]


def test_another_session_keeps_what_it_holds_and_leaving_with_nothing_is_harmless(
        rig: Rig) -> None:
    keeper, leaver = rig.connect(), rig.connect()
    keeper.ok("force t2.iMarcha 1")
    leaver.ok("status")
    leaver.close()
    wait_for(lambda: sum(x.name.startswith("socket") for x in rig.server.sessions) == 1,
             "the session to end")
    assert rig.state() == "running" and list(rig.plant.forced) == ["t2.iMarcha"]
    # the pause passes to the last session that paused
    leaver = rig.connect()
    leaver.ok("pause")
    keeper.ok("pause")
    leaver.close()
    wait_for(lambda: sum(x.name.startswith("socket") for x in rig.server.sessions) == 1,
             "the session to end")
    assert rig.state() == "paused"


def test_release_forces_on_disconnect_releases_without_a_halt(
        rigs: Callable[..., Rig]) -> None:
    """``release_forces_on_disconnect: true``: forces alone are released and the charts go
    on; a pause (or iocheck, or stepping) still halts."""
    rig = rigs(release=True)
    c = rig.connect()
    c.ok("force rio.Q0 1")
    c.close()
    wait_for(lambda: not rig.plant.forced_points, "rio.Q0 released")
    assert rig.state() == "running"
    c = rig.connect()
    c.ok("pause")
    c.close()
    wait_for(lambda: rig.state() == "halted", "the controller halted")


def test_the_server_stopping_releases_forces_without_a_halt(rig: Rig) -> None:
    s = rig.service.session("tcp:test", trusted=True, peer="tcp")
    s.feed(b"force rio.Q0 1\r\n")
    s.close("server stopping")
    assert not rig.plant.forced_points and rig.state() == "running"


def test_ack_after_a_fault_leaves_no_force(rig: Rig) -> None:
    """The attack: force an output, a fault, ack. Before: the output came back on."""
    s = rig.serial()
    s.ok("force rio.Q0 1")
    wait_for(lambda: outputs(rig)["Q0"] == 1, "rio.Q0 forced on")
    rig.driver.broken = "bus cable cut"
    wait_for(lambda: rig.state() == "fault", "the fault")
    rig.driver.broken = None
    wait_for(lambda: rig.daemon.call(rig.plant.faulted) is None, "the bus mended")
    out = s.ok("ack")
    assert out == ["fault acknowledged: charts restarted from their initial situation; "
                   "forces released: rio.Q0"]
    scans = rig.daemon.scan_stats.count
    wait_for(lambda: rig.daemon.scan_stats.count > scans + 3, "a few cycles")
    assert outputs(rig)["Q0"] == 0 and not rig.plant.forced_points
    assert not any(x.startswith("forced") for x in s.ok("status"))
    assert not rig.service.holdings()


def test_a_pause_ends_into_a_halt_after_its_maximum_time(rigs: Callable[..., Rig]) -> None:
    clock = FakeClock()
    rig = rigs(clock=clock)
    lim = rig.service.limits
    c = rig.connect()
    c.ok("pause")
    clock.t += lim.max_pause_s - lim.warn_before_s - 1
    c.ok("status")  # nothing said yet
    clock.t += 2
    assert c.line() == (f"warning: the pause ends in {lim.warn_before_s:.0f} s (max_pause "
                        f"{lim.max_pause_s:.0f} s): the controller then halts until 'ack'; "
                        "'pause' again keeps it")
    # 'pause' again restarts its time
    c.ok("pause")
    clock.t += lim.max_pause_s - 1
    assert c.line().startswith("warning: the pause ends in")
    assert rig.state() == "paused"
    clock.t += 1
    assert c.line() == (f"pause ended after {lim.max_pause_s:.0f} s (max_pause): every "
                        "output off, 'ack' restarts the charts")
    wait_for(lambda: rig.state() == "halted", "the halt")
    assert halted_reason(rig).startswith(f"the pause of console socket:{rig.socket_path} "
                                         f"lasted its maximum {lim.max_pause_s:.0f} s")
    assert set(outputs(rig).values()) == {0}
    c.ok("ack")
    assert rig.state() == "running"  # never an automatic resume: ack did it


def test_a_force_is_released_after_its_maximum_time(rigs: Callable[..., Rig]) -> None:
    clock = FakeClock()
    rig = rigs(clock=clock)
    lim = rig.service.limits
    c = rig.connect()
    c.ok("force rio.Q0 1")
    clock.t += 100
    c.ok("force t1.iMarcha 1")
    clock.t += lim.max_force_s - lim.warn_before_s - 100
    assert c.line() == (f"warning: force rio.Q0 is released in {lim.warn_before_s:.0f} s "
                        f"(max_force {lim.max_force_s:.0f} s); force it again to keep it")
    assert c.jcmd("json on")["ok"] is True  # notices are objects without "ok" in JSON
    clock.t += lim.warn_before_s
    assert json.loads(c.line()) == {
        "notice": f"force rio.Q0 released after {lim.max_force_s:.0f} s (max_force)"}
    wait_for(lambda: not rig.plant.forced_points, "rio.Q0 released")
    assert list(rig.plant.forced) == ["t1.iMarcha"] and rig.state() == "running"


def test_the_limits_come_from_the_plant_file(tmp_path: Path) -> None:
    path = tmp_path / "plant.yaml"
    base = "plc: {cycle: 10ms}\ndrivers: {rio: {type: sim}}\ninstances: {}\nmonitor:\n"
    path.write_text(base + "  limits: {max_pause: 2m, max_force: 1h, warn_before: 10s, "
                           "relock_after_idle: 90s}\n", encoding="utf-8")
    assert load_plant(str(path)).console_limits == ConsoleLimits(120.0, 3600.0, 10.0, 90.0)
    path.write_text(base + "  socket: /tmp/x.sock\n", encoding="utf-8")
    assert load_plant(str(path)).console_limits == ConsoleLimits()
    assert ConsoleLimits() == ConsoleLimits(900.0, 900.0, 30.0, 300.0)
    for bad, msg in (("{max_pause: 0}", "max_pause must be more than 0"),
                     ("{warn_before: 20m}", "must be longer than warn_before"),
                     ("{max_pause: 5}", "bad time literal"),
                     ("{max_paus: 5m}", "unknown key 'max_paus'")):
        path.write_text(base + f"  limits: {bad}\n", encoding="utf-8")
        with pytest.raises(SourceError, match=msg):
            load_plant(str(path))
