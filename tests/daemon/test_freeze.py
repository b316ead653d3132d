"""A frozen process (SIGSTOP, a paused VM, a suspended system) is noticed when it runs
again: on a virtual clock here, with a real SIGSTOP of a real controller below.

The scan thread sees a freeze as the lateness of its wake-up (CLOCK_MONOTONIC runs on
during SIGSTOP) or as a jump of CLOCK_BOOTTIME against CLOCK_MONOTONIC (the monotonic
clock stands still while the system is suspended). A freeze longer than the watchdog is a
fault; the watchdog thread, frozen too, does not blame the scan thread for it."""

from __future__ import annotations

import re
import signal
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.controller.scheduler import Scheduler, Watchdog
from tests.daemon.daemonkit import wait_until
from tests.daemon.test_daemon_process import Console, coils, plant, start, stop
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

MS = 1_000_000


class Clocks:
    """A virtual CLOCK_MONOTONIC and CLOCK_BOOTTIME; ``suspend`` moves only the second."""

    def __init__(self) -> None:
        self.mono = 5 * MS
        self.boot_offset = 1_000 * MS

    def clock(self) -> int:
        return self.mono

    def boot(self) -> int:
        return self.mono + self.boot_offset


def run_with(events: dict[int, tuple[str, int]], cycles: int = 6, cycle: int = 10 * MS,
             watchdog: int = 100 * MS) -> tuple[Scheduler, list[int], list[int]]:
    """Run ``cycles`` 1 ms scans; before wake-up k, ``events[k]`` is ("late", ns): the
    process did not run for ns after the deadline, or ("suspend", ns): the system slept."""
    ck = Clocks()
    frozen: list[int] = []
    wakes: list[int] = []

    def sleep_until(deadline: int) -> None:
        ck.mono = max(ck.mono, deadline)
        kind, ns = events.get(len(wakes), ("", 0))
        if kind == "late":
            ck.mono += ns
        elif kind == "suspend":
            ck.boot_offset += ns

    def body(now: int) -> None:
        wakes.append(now)
        ck.mono += 1 * MS

    s = Scheduler(body, cycle, watchdog, on_freeze=frozen.append, clock=ck.clock,
                  boot_clock=ck.boot, sleep_until=sleep_until, manage_gc=False)
    s.run(cycles=cycles)
    return s, frozen, wakes


def test_a_wake_up_later_than_the_watchdog_is_a_freeze() -> None:
    s, frozen, wakes = run_with({2: ("late", 1500 * MS), 4: ("late", 60 * MS)})
    assert frozen == [1500 * MS]  # 60 ms late is lateness, not a freeze
    assert s.stats.freezes == 1 and s.stats.freeze_max == 1500 * MS
    assert s.stats.as_dict()["freezes"] == 1
    assert s.stats.as_dict()["freeze_max_ms"] == 1500.0
    # the overrun policy is unchanged: no catch-up burst after the freeze
    assert min(b - a for a, b in zip(wakes, wakes[1:], strict=False)) >= 10 * MS


def test_a_system_suspend_is_a_freeze_though_the_monotonic_clock_stood_still() -> None:
    s, frozen, wakes = run_with({3: ("suspend", 30_000 * MS), 5: ("suspend", 50 * MS)})
    assert frozen == [30_000 * MS]
    assert s.stats.freezes == 1
    assert s.stats.late_max == 0  # invisible to the monotonic clock


def test_no_freeze_on_a_regular_run() -> None:
    s, frozen, _ = run_with({})
    assert frozen == [] and s.stats.freezes == 0


class _Sched:
    """What the watchdog reads of a scheduler."""

    def __init__(self) -> None:
        self.cycle_ns = 10 * MS
        self.scanning_since = 0
        self.last_wake = 0


def test_the_watchdog_thread_does_not_blame_the_scan_for_a_freeze() -> None:
    # tick by tick on a virtual clock (the thread is not started); a 10 ms cycle
    sched, trips = _Sched(), list[int]()
    wd = Watchdog(sched, 100 * MS, trips.append)  # type: ignore[arg-type]
    for t in range(0, 100, 25):
        sched.last_wake = t * MS
        wd.tick(t * MS + 1 * MS)
    # the whole process was stopped for 1.5 s; the watchdog thread runs first
    wd.tick(1575 * MS)
    assert trips == [], "the frozen scan thread was blamed for the freeze"
    assert wd.freezes == 1
    # its last look was at 76 ms, then one period (25 ms) of waiting is no freeze
    assert wd.froze_during(70 * MS, 1580 * MS) == 1474 * MS
    assert wd.froze_during(1600 * MS, 1700 * MS) == 0
    for t in range(1600, 1800, 25):  # the scan thread wakes up and carries on
        sched.last_wake = t * MS - 3 * MS
        wd.tick(t * MS)
    assert trips == []
    # frozen again, and this time the scan thread does not come back: it is stuck
    wd.tick(3800 * MS)
    assert wd.freezes == 2 and trips == []
    for t in range(3825, 4000, 25):
        wd.tick(t * MS)
    assert len(trips) == 1 and trips[0] > 2000 * MS


def test_after_a_freeze_no_ping_until_the_scan_thread_has_woken() -> None:
    sched, pings = _Sched(), list[int]()
    wd = Watchdog(sched, 100 * MS, lambda ns: None,  # type: ignore[arg-type]
                  ping=lambda: pings.append(1), ping_interval_ns=10 * MS)
    sched.last_wake = sched.scanning_since = 1 * MS  # a scan that hangs from 1 ms on
    wd.tick(2 * MS)
    assert pings == [1]
    wd.tick(500 * MS)  # this thread was starved (or frozen): not the scan's fault...
    for t in range(525, 600, 25):
        wd.tick(t * MS)  # ...but no vouching for a scan thread that has not run since
    assert pings == [1]
    sched.scanning_since, sched.last_wake = 0, 610 * MS
    wd.tick(611 * MS)
    assert pings == [1, 1]


def test_a_freeze_the_watchdog_thread_has_not_seen_yet_is_told_by_its_silence() -> None:
    sched = _Sched()
    wd = Watchdog(sched, 100 * MS, lambda ns: None)  # type: ignore[arg-type]
    sched.last_wake = 1 * MS
    wd.tick(2 * MS)
    # a scan from 10 ms to 1530 ms, frozen inside: it ends before this thread runs again
    assert wd.froze_during(10 * MS, 1530 * MS) == 1503 * MS
    # a scan that was merely slow while this thread kept looking is no freeze
    for t in range(25, 1525, 25):
        wd.tick(t * MS)
    assert wd.froze_during(10 * MS, 1530 * MS) == 0


@pytest.fixture
def line() -> Iterator[tuple[PtyBridge, ModbusPeer]]:
    with PtyBridge() as bridge, ModbusPeer(bridge.peer_port, (1,)) as peer:
        yield bridge, peer


def test_sigstop_longer_than_the_watchdog_is_a_fault(tmp_path: Path,
                                                      line: tuple[PtyBridge, ModbusPeer]
                                                      ) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])  # iGo
    sock = tmp_path / "console.sock"
    # a watchdog a loaded test machine keeps (starved of CPU longer than the watchdog,
    # the process is frozen too), well below the 1.5 s of the attack
    proc = start(plant(tmp_path, bridge.driver_port, tolerant=True), {})
    con = Console(sock)
    spans: list[float] = []  # ms from SIGSTOP to SIGCONT, as this process sent them
    try:
        for n in range(1, 4):
            wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
            assert "state running" in con.cmd("status")
            t_stop = time.monotonic()
            proc.send_signal(signal.SIGSTOP)
            time.sleep(1.5)  # the attack: three watchdog times without running
            proc.send_signal(signal.SIGCONT)
            spans.append((time.monotonic() - t_stop) * 1e3)
            wait_until(lambda: "state fault" in con.cmd("status"), 20,
                       "a fault after the freeze")
            status = con.cmd("status")
            found = re.search(r"frozen for (\d+) ms", status)
            assert found and frozen_as_sent(int(found.group(1)), spans[-1]), (status, spans)
            wait_until(lambda: coils(peer) == [0, 0], 20, "outputs off")
            assert con.json("stats")["stats"]["freezes"] == n
            assert con.json("ack")["ok"] is True
    finally:
        con.close()
        code, err = stop(proc)
    assert code == 0, err
    told = [int(ms) for ms in re.findall(r"FAULT: frozen for (\d+) ms", err)]
    assert len(told) == 3, err
    assert all(frozen_as_sent(ms, span) for ms, span in zip(told, spans, strict=True)), (
        told, spans, err)


def frozen_as_sent(ms: int, span_ms: float) -> bool:
    """The freeze told is the stop the test made: at least most of the 1.5 s slept, at
    most what passed between the two signals as this process sent them (a pause of this
    process makes that longer) and a cycle and a scan more."""
    return 1400 <= ms <= span_ms + 200
