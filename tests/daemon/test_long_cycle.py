"""A long cycle (up to the longest a plant may set, 1 min) keeps the controller reachable: a
request of the console or of a reload is served when it comes, not at the next cycle, and
a stop ends the wait at once. Before, with ``cycle: 1h``, every console request timed out
("the scan thread did not answer") and a stop took 7 s, the scan thread left behind."""

from __future__ import annotations

import logging

import pytest

from runtime.controller.scheduler import AWAKE_CYCLE_NS
from runtime.engine.commands import CommandRefused
from runtime.language.plantfile import PLC
from tests.console.consolekit import make_rig, wait_for
from tests.daemon.daemonkit import MakeDaemon, wait_until

LONGEST = "1m"


def test_the_longest_cycle_is_one_minute() -> None:
    assert PLC["cycle"].high == 60 * 10**9 > AWAKE_CYCLE_NS


def test_requests_are_served_at_once_in_a_one_minute_cycle(make_daemon: MakeDaemon) -> None:
    daemon, drv = make_daemon(cycle=LONGEST)
    wait_until(lambda: daemon.scan_stats.count >= 1, what="the first scan")
    for n in range(3):  # each within Daemon.call's own 2 s, many times over
        assert daemon.call(lambda: daemon.plant.get("m.sN")) == 0, n
    with pytest.raises(CommandRefused, match="nothing to acknowledge"):
        daemon.ack()
    assert daemon.scan_stats.count == 1  # served between two cycles, no extra scan


def test_a_stop_in_a_one_minute_cycle_is_at_once(make_daemon: MakeDaemon,
                                                  caplog: pytest.LogCaptureFixture) -> None:
    daemon, drv = make_daemon(cycle=LONGEST)
    wait_until(lambda: daemon.scan_stats.count >= 1, what="the first scan")
    with caplog.at_level(logging.INFO):
        daemon.stop("end of test")
    assert daemon.wait(0), "the scan thread still waits for its next cycle"
    assert not [r for r in caplog.records if "did not stop" in r.getMessage()]
    assert drv.last()[0] == "safe"


def test_the_console_answers_in_a_one_minute_cycle() -> None:
    rig = make_rig(serial_port=False, cycle=LONGEST)
    try:
        wait_for(lambda: rig.daemon.scan_stats.count >= 1, "the first scan")
        assert rig.socket_path is not None
        c = rig.connect()
        status = c.ok("status")
        assert not any("did not answer" in line for line in status), status
        c.ok("pause")  # a changing command: served by the scan thread, between two cycles
        assert rig.state() == "paused"
        c.ok("resume")
        c.close()
    finally:
        rig.close()
    assert rig.daemon.wait(0)
