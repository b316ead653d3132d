"""A console pause freezes the program's clock, end to end: the daemon on its real clock,
the console over a real pty (tests/console/consolekit.py), the drawer tester's step time."""

from __future__ import annotations

import re
from collections.abc import Iterator

import pytest

from tests.console.consolekit import Rig, make_rig, wait_for

MS = 1_000_000
#: how long the chart stays paused (s): far more than one cycle of 10 ms
PAUSED_S = 1.5


@pytest.fixture
def rig() -> Iterator[Rig]:
    r = make_rig()
    try:
        yield r
    finally:
        r.close()


def test_cycle_1_after_a_long_pause_moves_the_step_time_by_one_cycle(rig: Rig) -> None:
    s = rig.serial()
    rig.set_input("I1", 1)  # start: tester 1 opens the drawer (gsAbrir, .T running)
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 in gsAbrir")
    s.ok("pause")
    frozen = rig.read("t1.gsAbrir.T")
    paused_at = rig.daemon.clock()
    scans = rig.daemon.scan_stats.count
    # the daemon's own clock moves on by PAUSED_S while its cycles go on, paused
    wait_for(lambda: rig.daemon.clock() - paused_at > PAUSED_S * 1e9
             and rig.daemon.scan_stats.count > scans, f"{PAUSED_S} s of paused cycles",
             timeout=PAUSED_S + 30)
    scans = rig.daemon.scan_stats.count
    wait_for(lambda: rig.daemon.scan_stats.count > scans, "one more paused cycle")
    assert rig.read("t1.gsAbrir.T") == frozen
    assert s.ok("cycle 1")[1:] == ["nothing changed"]  # step times are left out
    assert rig.read("t1.gsAbrir.T") == frozen + 10 * MS
    (line,) = s.ok("get t1.gsAbrir.T")
    # the value, then the step's description from the I/O list (docs/console.md, get)
    got = re.fullmatch(r"t1\.gsAbrir\.T=(?:(\d+)s)?(?:(\d+)ms)?(?:  \"[^\"]*\")?", line)
    assert got is not None, line
    shown_ms = int(got[1] or 0) * 1000 + int(got[2] or 0)
    assert shown_ms == round((frozen + 10 * MS) / MS)
    resumed_at = rig.daemon.clock()
    s.ok("resume")
    wait_for(lambda: rig.read("t1.gsAbrir.T") > frozen + 10 * MS, "t1 running again")
    t = rig.read("t1.gsAbrir.T")
    since = rig.daemon.clock() - resumed_at  # measured after the read: a scan may run
    # between two reads (a loaded run once read .T again after measuring, 0.24 ms over)
    # no jump: one cycle for the first scan after resume, then the clock's own time
    assert t <= frozen + 20 * MS + since
