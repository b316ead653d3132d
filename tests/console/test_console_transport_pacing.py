"""The console's pacing: on a virtual clock, the quiet time before each scan and the share
of a processor (ScanWindow) and the rate of a session (Throttle); on a running daemon,
how often ``stats`` computes its percentiles."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from runtime.console.server import (
    BURST_LINES,
    CPU_SHARE,
    LINES_PER_S,
    QUIET_BEFORE_S,
    ROUND_BUDGET_S,
    STALE_S,
    ScanWindow,
    Throttle,
)
from runtime.controller.daemon import STATS_MAX_AGE_NS, STATS_QUANTILES_MAX_AGE_NS
from tests.console.consolekit import Rig, wait_for


class VirtualTime:
    """A clock and a sleep that moves it; a scan ends at each time of ``scans`` that the
    clock passes (the window hears of it as from the scan thread), its next deadline a
    cycle after the last one."""

    def __init__(self, cycle_s: float) -> None:
        self.t = 100.0
        self.cycle_s = cycle_s
        self.slept: list[float] = []
        self.window: ScanWindow | None = None
        self.scans: list[float] = []
        #: the deadline of the next scan (the scheduler's ``due``)
        self.deadline = 100.0

    def clock(self) -> float:
        return self.t

    def due(self) -> float:
        return self.deadline

    def sleep(self, s: float) -> None:
        self.slept.append(s)
        self.t += s
        while self.scans and self.t >= self.scans[0]:  # the scan thread ran meanwhile
            self.scan_ends(self.scans.pop(0))

    def wait(self, timeout: float) -> None:
        """Until the next scan has ended, or ``timeout``."""
        self.sleep(min(timeout, self.scans[0] - self.t) if self.scans else timeout)

    def scan_ends(self, at: float) -> None:
        """A scan ended at ``at``: the next one is due a cycle after its deadline."""
        assert self.window is not None
        self.deadline += self.cycle_s
        now, self.t = self.t, at
        self.window.on_scan(0)
        self.t = now


def window(cycle_s: float, **options: float) -> tuple[ScanWindow, VirtualTime]:
    """A window whose first scan ended on time at 100.0."""
    vt = VirtualTime(cycle_s)
    w = ScanWindow(cycle_s, clock=vt.clock, sleep=vt.sleep, due=vt.due, wait=vt.wait,
                   **options)
    vt.window = w
    vt.scan_ends(100.0)
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
    # the quiet time before the scan after it, however late this one ended
    assert closes == pytest.approx(100.0 + cycle_s + open_s)


def test_a_late_scan_leaves_a_shorter_window_not_a_shorter_quiet_time() -> None:
    """A scan woken 4 ms late at a 10 ms cycle (a loaded machine) ends 6 ms before the
    next deadline: the window closes QUIET_BEFORE_S before that deadline, 1 ms after the
    scan, not a cycle less the quiet time after it (which left 1 ms of quiet time)."""
    w, vt = window(0.010)
    vt.t = 100.0 + 0.006  # closed
    vt.scans = [100.014]
    closes = w.until()
    assert vt.t == pytest.approx(100.014)
    assert closes == pytest.approx(100.020 - QUIET_BEFORE_S)


def test_a_stuck_scan_does_not_stop_the_console() -> None:
    """No scan ended for STALE_S (stuck, or stopped): the console works anyway, so
    ``status`` still answers. A scan merely late (a busy machine: tens of ms) still finds
    the console waiting for it."""
    w, vt = window(0.010)
    vt.t += 0.030
    w.until()
    assert vt.t == pytest.approx(100.0 + STALE_S, abs=0.001)  # waited for a scan till then
    vt.t += 0.001
    assert w.until() == pytest.approx(vt.t + ROUND_BUDGET_S) and vt.slept


@pytest.mark.parametrize("stuck", [False, True])
def test_the_console_takes_at_most_its_share_of_a_processor(stuck: bool) -> None:
    """Work reported with ``spend`` waits for the budget to come back at CPU_SHARE of
    the time, at most CPU_SHARE of a cycle at once: over 10 s of a flood of 0.25 ms
    requests, at most a tenth of that time and one burst went to them. Running, it all
    comes right after each scan (a 10 ms cycle's share, 1 ms, at once), never later in
    the window; with the scan stuck (the windows always open), spread over the time."""
    w, vt = window(0.010)
    assert w.burst_s == pytest.approx(CPU_SHARE * 0.010)
    spent = 0.0
    start = vt.t
    while vt.t < start + 10.0:
        if not stuck and not vt.scans:
            vt.scans.append(vt.deadline + 0.0002)  # each scan ends 0.2 ms after it is due
        slot = w.slot()
        assert vt.t < slot.closes
        if not stuck:
            assert slot.closes == pytest.approx(vt.deadline - QUIET_BEFORE_S)
            assert vt.t - w.scan_end < w.burst_s + 1e-9  # right after the scan
        w.spend(0.00025)
        spent += 0.00025
        vt.t += 0.00025
    assert spent <= CPU_SHARE * (vt.t - start) + w.burst_s + 0.00025
    assert spent >= 0.9 * CPU_SHARE * 10.0  # and the share is there to be used


def test_a_slot_may_be_waited_in_only_until_a_quiet_time_before_it_closes() -> None:
    """A thread may wait for input inside a window only until ``settles``, a second
    quiet time before it closes: at a 10 ms cycle never (one stretch right after the
    scan), at a 1 s cycle until 10 ms before the next scan is due."""
    w, vt = window(0.010)
    slot = w.slot()
    assert slot.settles == pytest.approx(vt.t) and slot.closes == pytest.approx(100.005)
    w, vt = window(1.0)
    slot = w.slot()
    assert slot.settles == pytest.approx(101.0 - 2 * QUIET_BEFORE_S)


def test_a_long_computation_pauses_into_the_next_window() -> None:
    """``pause()`` between the slices of a long computation (the percentiles of
    ``stats``): a short sleep inside the window; once it has closed, until the next scan
    has ended, so that no slice holds the GIL across the scan's deadline."""
    w, vt = window(0.010)
    w.pause()
    assert vt.t == pytest.approx(100.0001)  # inside: a short sleep
    vt.t = 100.0 + 0.006  # the window closed at 100.005
    vt.scans = [100.0102]
    w.pause()
    assert vt.t == pytest.approx(100.0102)  # the next window


def test_a_session_runs_its_rate_and_its_burst() -> None:
    vt = VirtualTime(0.010)
    th = Throttle(vt.clock)
    assert all(th.take() for _ in range(BURST_LINES))
    assert not th.take()
    assert th.next_token() == pytest.approx(vt.t + 1 / LINES_PER_S)
    vt.t += 1.0  # a second later: LINES_PER_S more, not more
    assert sum(th.take() for _ in range(3 * BURST_LINES)) == int(LINES_PER_S)
    vt.t += 3600.0  # a long pause: never more than the burst
    assert sum(th.take() for _ in range(3 * BURST_LINES)) == BURST_LINES


def test_stats_computes_its_figures_at_most_every_100_ms_and_percentiles_every_second(
        rigs: Callable[..., Rig]) -> None:
    """``stats`` percentiles of up to 8192 cycles cost a few ms of processor time:
    however many consoles ask, the daemon computes the figures once per STATS_MAX_AGE_NS
    of cycles and their percentiles once per STATS_QUANTILES_MAX_AGE_NS; meanwhile every
    caller gets the same dict (the console formats it once)."""
    rig = rigs(serial_port=False, unix_socket=False, cycle="2ms")
    stats = rig.daemon.scan_stats
    real_dict, real_quantiles = stats.as_dict, stats.window_quantiles
    made: list[int] = []
    sorts: list[int] = []

    def counting_dict(quantiles: Any = None) -> dict[str, Any]:
        made.append(stats.count)
        return real_dict(quantiles)

    def counting_quantiles(pause: Any = None) -> Any:
        sorts.append(stats.count)
        return real_quantiles(pause)
    stats.as_dict = counting_dict  # type: ignore[method-assign]
    stats.window_quantiles = counting_quantiles  # type: ignore[method-assign]
    first = stats.count
    replies = [rig.daemon.stats() for _ in range(500)]
    assert all(r is replies[0] for r in replies)
    per = STATS_MAX_AGE_NS // rig.plant.cycle_ns
    per_sort = STATS_QUANTILES_MAX_AGE_NS // rig.plant.cycle_ns
    wait_for(lambda: stats.count >= first + 3 * per, "three ages of cycles")
    replies += [rig.daemon.stats() for _ in range(500)]
    wait_for(lambda: stats.count >= first + per_sort + per, "a second of cycles")
    replies += [rig.daemon.stats() for _ in range(500)]
    last = stats.count
    assert 3 <= len(made) <= 3 + (last - first) // per, made
    assert all(b - a >= per for a, b in zip(made, made[1:], strict=False)), made
    assert len(sorts) == 2 and sorts[1] - sorts[0] >= per_sort, sorts
    assert replies[-1]["cycles"] >= last - per  # fresh within that age
