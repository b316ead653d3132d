"""Each command that changes the plant leaves one log line naming the console that gave
it (forces set and released, set, pause, resume, cycle, init, reset, iocheck, ack); and
the monitor shows what holds the charts (an instance's SFCPause, a console pause). Through
a real daemon with its console on a pty."""

from __future__ import annotations

import logging

import pytest

from runtime.console.client import ConsoleClient
from runtime.console.links import open_link
from runtime.console.view import View
from tests.console.conftest import rig, rigs  # noqa: F401 - the console's fixtures
from tests.console.consolekit import Rig, wait_for


def console_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in list(caplog.records)
            if r.name.startswith("runtime.console.changing")]


def test_every_changing_command_is_logged_once_with_its_console(
        rig: Rig, caplog: pytest.LogCaptureFixture) -> None:  # noqa: F811
    caplog.set_level(logging.INFO)
    s = rig.serial()
    who = f"console serial:{rig.modem.daemon_port if rig.modem else ''}"
    script = [
        ("force t1.iMarcha 1", f"{who}: force t1.iMarcha = 1"),
        ("unforce t1.iMarcha", f"{who}: force t1.iMarcha released"),
        ("set t1.sCierres 3", f"{who}: set t1.sCierres = 3"),
        ("pause", f"{who}: pause: charts held"),
        ("cycle 2", f"{who}: cycle 2: ran scans "),
        ("resume", f"{who}: resume: charts run"),
        ("init t2", f"{who}: init t2: SFCInit pulsed"),
        ("reset t2", f"{who}: reset t2: SFCReset pulsed"),
        ("force t2.iMarcha 1", f"{who}: force t2.iMarcha = 1"),
        ("iocheck on", f"{who}: iocheck on: charts stopped, every output off; released "
                       "forces: t2.iMarcha"),
        ("iocheck off", f"{who}: iocheck off: outputs off until ack"),
        ("ack", f"{who}: ack (halted: iocheck ended: 'ack' restarts the charts from their "
                f"initial situation): charts restarted from their initial situation"),
    ]
    for command, line in script:
        caplog.clear()
        s.ok(command)
        got = console_lines(caplog)
        assert len(got) == 1 and got[0].startswith(line), (command, got)


def test_unforce_all_and_an_ack_that_releases_forces_say_so(
        rig: Rig, caplog: pytest.LogCaptureFixture) -> None:  # noqa: F811
    caplog.set_level(logging.INFO)
    s = rig.serial()
    s.ok("force t1.iMarcha 1")
    s.ok("force t2.iMarcha 1")
    caplog.clear()
    s.ok("unforce all")
    got = console_lines(caplog)
    assert len(got) == 1 and got[0].endswith(
        ": every force released (t1.iMarcha, t2.iMarcha)"), got
    rig.driver.broken = "rio: no answer"
    wait_for(lambda: rig.state() == "fault", "the fault")
    rig.driver.broken = None
    wait_for(lambda: rig.daemon.call(rig.plant.faulted) is None, "the driver back")
    s.ok("force t1.iMarcha 1")
    caplog.clear()
    s.ok("ack")
    got = console_lines(caplog)
    assert len(got) == 1, got
    assert got[0].endswith(": ack (fault: driver rio: rio: no answer): fault acknowledged: "
                           "charts restarted from their initial situation; forces "
                           "released: t1.iMarcha"), got


def test_a_refused_command_is_not_logged(rig: Rig,  # noqa: F811
                                         caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    s = rig.serial()
    caplog.clear()
    s.error("cycle 1")  # not paused
    s.error("ack")  # nothing to acknowledge
    assert console_lines(caplog) == []


def test_the_monitor_shows_what_holds_the_charts(rig: Rig) -> None:  # noqa: F811
    assert rig.socket_path is not None
    client = ConsoleClient(open_link(rig.socket_path))
    client.start()
    try:
        view = View(target="bench")
        view.command(client, "set t1.SFCPause 1")
        view.refresh(client)
        text = view.lines(100)
        assert text[0] == "softplc monitor bench   state RUNNING"
        assert "inhibit  t1: held by SFCPause" in text, text
        view.command(client, "pause")
        view.refresh(client)
        text = view.lines(100)
        assert text[0] == "softplc monitor bench   state PAUSED"
        assert "inhibit  paused by the console: charts held" in text, text
        assert "inhibit  t1: held by SFCPause" in text, text
        view.command(client, "resume")
        view.command(client, "set t1.SFCPause 0")
        view.refresh(client)
        assert not [x for x in view.lines(100) if x.startswith("inhibit")]
    finally:
        client.close()
