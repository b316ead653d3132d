"""The alarms at the console (issue 29): the console's ``status``, the monitor and the
log say the same alarm states (runtime/controller/alarms.py), over a real Unix socket
console of the drawer tester (configs/drawer_tester, its I/O list in Spanish): an
SFCError set by hand is an ``INSTANCE.SFCError`` alarm named with the instance's
description; the console's ``ack`` clears its cause, the alarm stays to be acknowledged."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from runtime.console.client import ConsoleClient
from runtime.console.links import Target
from runtime.console.view import View
from tests.console.consolekit import socket_client
from tests.console.test_console_iolist import DRAWER, console

KEY = "tester1.SFCError"
TEXT = "tester1 (Banco de ensayo de guías de cajón 1): SFCError set by the chart"
#: what status and the monitor say of an SFCError no step's max time set
CAUSE = "SFCError tester1: set by the chart"
#: how long the alarm board may take to see a change on a loaded machine, s
DEADLINE_S = 15.0


def alarm_of(lines: list[str]) -> list[str]:
    """The tester's alarm lines (a loaded machine may add a freeze fault of its own)."""
    return [x for x in lines if x.startswith(f"alarm {KEY} ")]


def test_status_the_monitor_and_the_log_show_the_same_alarm(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "runtime.controller.alarms")
    with console(DRAWER, tmp_path) as (daemon, sock):
        s = socket_client(sock)
        assert alarm_of(s.ok("status")) == []
        s.ok(f"set {KEY} 1")
        end = time.monotonic() + DEADLINE_S
        while not alarm_of(shown := s.ok("status")):
            assert time.monotonic() < end, shown
            time.sleep(0.05)
        assert alarm_of(shown) == [f"alarm {KEY} (700) active, unacknowledged, "
                                   f"unconfirmed: {TEXT}"]
        assert CAUSE in shown, shown  # it said 'SFCError tester1: step ' (no step)
        client = ConsoleClient(Target.parse(sock).open())
        client.start()
        view = View(sock)
        view.refresh(client)
        client.close()
        assert alarm_of([x.strip() for x in view.lines(200)]) == alarm_of(shown)
        assert CAUSE in [x.strip() for x in view.lines(200)]
        assert s.ok("ack") == ["SFCError of tester1 (set by the chart) acknowledged"]
        end = time.monotonic() + DEADLINE_S
        while "active," in " ".join(alarm_of(shown := s.ok("status"))).replace(
                "inactive,", ""):
            assert time.monotonic() < end, shown
            time.sleep(0.05)
        assert alarm_of(shown) == [f"alarm {KEY} (700) inactive, unacknowledged, "
                                   f"unconfirmed: {TEXT}"]
        s.close()
    said = [r.getMessage() for r in caplog.records if r.name == "runtime.controller.alarms"
            and r.getMessage().startswith(f"alarm {KEY} ")]
    assert said == [f"alarm {KEY} raised (severity 700): {TEXT}",
                    f"alarm {KEY} cleared (inactive, unacknowledged, unconfirmed): {TEXT}"]
