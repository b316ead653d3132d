"""The console's pacing on a virtual clock: the quiet time before each scan (ScanWindow)
and the rate of a session (Throttle)."""

from __future__ import annotations

import pytest

from runtime.console.server import (
    BURST_LINES,
    LINES_PER_S,
    QUIET_BEFORE_S,
    ROUND_BUDGET_S,
    ScanWindow,
    Throttle,
)


class VirtualTime:
    """A clock and a sleep that moves it; a scan ends when the clock passes ``scans``."""

    def __init__(self, window: ScanWindow | None = None) -> None:
        self.t = 100.0
        self.slept: list[float] = []
        self.window = window
        self.scans: list[float] = []

    def clock(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s
        while self.scans and self.t >= self.scans[0]:  # the scan thread ran meanwhile
            assert self.window is not None
            self.window.scan_end = self.scans.pop(0)


def window(cycle_s: float) -> tuple[ScanWindow, VirtualTime]:
    vt = VirtualTime()
    w = ScanWindow(cycle_s, clock=vt.clock, sleep=vt.sleep)
    vt.window = w
    w.on_scan(0)
    return w, vt


@pytest.mark.parametrize(("cycle_s", "open_s"), [(0.010, 0.005), (1.0, 1.0 - QUIET_BEFORE_S),
                                                 (0.002, 0.001)])
def test_console_work_stops_before_the_next_scan_until_it_has_ended(
        cycle_s: float, open_s: float) -> None:
    w, vt = window(cycle_s)
    assert w.until() == pytest.approx(100.0 + open_s) and not vt.slept
    vt.t += open_s - 1e-6
    assert w.until() == pytest.approx(100.0 + open_s) and not vt.slept  # still open
    vt.t += 2e-6  # closed: sleeps until the next scan has ended
    vt.scans = [100.0 + cycle_s + 0.0003]
    closes = w.until()
    assert vt.t >= 100.0 + cycle_s + 0.0003 and vt.slept
    assert closes == pytest.approx(100.0 + cycle_s + 0.0003 + open_s)


def test_a_stuck_scan_does_not_stop_the_console() -> None:
    """No scan ended for two cycles (stuck, or stopped): the console works anyway, so
    ``status`` still answers."""
    w, vt = window(0.010)
    vt.t += 0.0201
    assert w.until() == pytest.approx(vt.t + ROUND_BUDGET_S) and not vt.slept


def test_a_session_runs_its_rate_and_its_burst() -> None:
    vt = VirtualTime()
    th = Throttle(vt.clock)
    assert all(th.take() for _ in range(BURST_LINES))
    assert not th.take()
    assert th.next_token() == pytest.approx(vt.t + 1 / LINES_PER_S)
    vt.t += 1.0  # a second later: LINES_PER_S more, not more
    assert sum(th.take() for _ in range(3 * BURST_LINES)) == int(LINES_PER_S)
    vt.t += 3600.0  # a long pause: never more than the burst
    assert sum(th.take() for _ in range(3 * BURST_LINES)) == BURST_LINES
