"""The interpreter's GIL switch interval while a controller runs: the longest its scan
waits for the GIL held by another of its threads before that thread is made to let it
go. 0.5 ms at most, and a tenth of a shorter cycle's: at a 1 ms cycle, 0.5 ms was half
the cycle, and the feed's and the console's threads ran that long while a late scan
waited (bench.observers --who). Restored when the controller stops."""

from __future__ import annotations

import sys

import pytest

from runtime.controller.daemon import GIL_SWITCH_S
from tests.daemon.daemonkit import MakeDaemon


@pytest.mark.parametrize(("cycle", "interval_s"), [
    ("1ms", 0.0001), ("2ms", 0.0002), ("10ms", GIL_SWITCH_S), ("100ms", GIL_SWITCH_S)])
def test_the_switch_interval_is_a_tenth_of_a_short_cycle(
        make_daemon: MakeDaemon, cycle: str, interval_s: float) -> None:
    was = sys.getswitchinterval()
    daemon, _ = make_daemon(cycle=cycle, watchdog="200ms")
    try:
        assert sys.getswitchinterval() == pytest.approx(interval_s, rel=0.01)
    finally:
        daemon.stop("end of test")
    assert sys.getswitchinterval() == was


def test_a_shorter_interval_set_before_is_kept(make_daemon: MakeDaemon) -> None:
    was = sys.getswitchinterval()
    sys.setswitchinterval(0.00005)
    short = sys.getswitchinterval()  # as the interpreter keeps it (whole µs)
    try:
        daemon, _ = make_daemon(cycle="10ms")
        assert sys.getswitchinterval() == short
        daemon.stop("end of test")
        assert sys.getswitchinterval() == short
    finally:
        sys.setswitchinterval(was)
