"""The console's pacing: on a virtual clock, the quiet time before each scan (ScanWindow)
and the rate of a session (Throttle); on a running daemon, how often ``stats`` sorts."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from runtime.console.server import (
    BURST_LINES,
    LINES_PER_S,
    QUIET_BEFORE_S,
    ROUND_BUDGET_S,
    ScanWindow,
    Throttle,
)
from runtime.controller.daemon import STATS_MAX_AGE_NS
from tests.console.consolekit import Rig, wait_for


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


def test_stats_sorts_the_cycle_window_at_most_every_100_ms_of_cycles(
        rigs: Callable[..., Rig]) -> None:
    """``stats`` percentiles sort up to 8192 cycles (~3 ms holding the GIL): however many
    consoles ask, the daemon computes them once per STATS_MAX_AGE_NS of cycles."""
    rig = rigs(serial_port=False, unix_socket=False)
    real = rig.daemon.scan_stats.as_dict
    sorts: list[int] = []

    def counting() -> dict[str, Any]:
        sorts.append(rig.daemon.scan_stats.count)
        return real()
    rig.daemon.scan_stats.as_dict = counting  # type: ignore[method-assign]
    first = rig.daemon.scan_stats.count
    replies = [rig.daemon.stats() for _ in range(500)]
    wait_for(lambda: rig.daemon.scan_stats.count >= first + 30, "30 cycles")
    replies += [rig.daemon.stats() for _ in range(500)]
    last = rig.daemon.scan_stats.count
    per = STATS_MAX_AGE_NS // rig.plant.cycle_ns
    assert 2 <= len(sorts) <= 2 + (last - first) // per, sorts
    assert all(b - a >= per for a, b in zip(sorts, sorts[1:], strict=False)), sorts
    assert replies[-1]["cycles"] >= first + 30 - per  # fresh within that age
