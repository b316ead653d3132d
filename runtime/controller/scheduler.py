"""The scan loop: one cycle per absolute deadline ``start + k·cycle`` on the monotonic clock.

Per cycle: sleep until the deadline, run the cycle body (read inputs, scan, write
outputs), record scan time and wake-up lateness, then spend what is left of the period on
the idle work (console requests, systemd pings, retain hand-off, garbage collection),
never past a guard band before the next deadline.

Overrun policy: when a cycle ends at or after the next deadline, the overrun is counted,
the deadlines it passed are counted as skipped, and the schedule is re-anchored one full
period after the end of the late cycle. There is never a burst of back-to-back catch-up
scans (OpenPLC's behaviour): the process sees one late cycle, then the normal period.

A scan longer than ``watchdog_ns`` is a fault, detected twice: by the loop when the scan
returns, and by ``Watchdog``, a thread that acts while a scan hangs.
"""

from __future__ import annotations

import gc
import logging
import threading
import time
from collections.abc import Callable

from runtime.controller.realtime import make_sleep_until
from runtime.controller.stats import ScanStats

log = logging.getLogger(__name__)

#: idle work stops this long before the next deadline, ns (and never less than a fifth
#: of the period)
GUARD_NS = 300_000
#: young-generation collections run in the idle time once this many objects are pending
GC_GEN0_THRESHOLD = 700
#: a full collection at most this often, ns, and only when the idle time allows it
GC_FULL_EVERY_NS = 60_000_000_000


class Scheduler:
    """Paces ``body(now)`` to absolute deadlines; ``run()`` is the scan thread's loop.

    ``idle(deadline_ns)`` is called after each cycle and must return before
    ``deadline_ns``; ``on_watchdog(scan_ns)`` when a scan took longer than the watchdog.
    The clock and the sleep are injectable, so tests run the loop on virtual time."""

    def __init__(self, body: Callable[[int], None], cycle_ns: int, watchdog_ns: int, *,
                 idle: Callable[[int], None] | None = None,
                 on_watchdog: Callable[[int], None] | None = None,
                 clock: Callable[[], int] = time.monotonic_ns,
                 sleep_until: Callable[[int], None] | None = None,
                 stats: ScanStats | None = None, manage_gc: bool = True) -> None:
        self.body = body
        self.cycle_ns = cycle_ns
        self.watchdog_ns = watchdog_ns
        self.idle = idle
        self.on_watchdog = on_watchdog
        self.clock = clock
        self.sleep_until = sleep_until or make_sleep_until()
        self.stats = stats or ScanStats()
        self.manage_gc = manage_gc
        self.guard_ns = max(GUARD_NS, cycle_ns // 5)
        #: monotonic ns at which the current scan started, 0 between scans (Watchdog reads it)
        self.scanning_since = 0
        #: monotonic ns of the last wake-up, 0 before the first (Watchdog reads it)
        self.last_wake = 0
        self.stop_event = threading.Event()
        self._last_full_gc = 0

    def run(self, cycles: int | None = None) -> None:
        """Run until ``stop_event`` is set (or ``cycles`` cycles, for tests)."""
        clock, cycle, stats, body = self.clock, self.cycle_ns, self.stats, self.body
        stop = self.stop_event
        gc_was_enabled = gc.isenabled()
        if self.manage_gc:
            gc.collect()
            gc.freeze()  # start-up objects (compiled charts, plant) are never scanned again
            gc.disable()
        deadline = clock()
        self._last_full_gc = deadline
        n = 0
        try:
            while not stop.is_set() and (cycles is None or n < cycles):
                self.sleep_until(deadline)
                wake = clock()
                self.scanning_since = self.last_wake = wake
                body(wake)
                end = clock()
                self.scanning_since = 0
                scan = end - wake
                stats.record(scan, wake - deadline)
                n += 1
                if scan > self.watchdog_ns and self.on_watchdog is not None:
                    self.on_watchdog(scan)
                deadline += cycle
                if end >= deadline:
                    stats.overruns += 1
                    stats.skipped += (end - deadline) // cycle
                    deadline = end + cycle
                if self.idle is not None:
                    self.idle(deadline - self.guard_ns)
                if self.manage_gc:
                    self._collect(deadline - self.guard_ns)
        finally:
            self.scanning_since = self.last_wake = 0
            if self.manage_gc:
                gc.unfreeze()
                if gc_was_enabled:
                    gc.enable()

    def _collect(self, until: int) -> None:
        """Garbage collection in the idle part of the cycle only."""
        if gc.get_count()[0] < GC_GEN0_THRESHOLD:
            return
        t0 = self.clock()
        if t0 >= until:
            return  # no idle time left: try after the next cycle
        full = t0 - self._last_full_gc >= GC_FULL_EVERY_NS
        gc.collect(2 if full else 0)
        if full:
            self._last_full_gc = t0
        self.stats.gc_runs += 1
        self.stats.gc_ns += self.clock() - t0


class Watchdog:
    """A thread that calls ``trip(running_ns)`` once when a scan of ``scheduler`` has been
    running longer than ``watchdog_ns``, or the loop has not woken up for a cycle plus
    ``watchdog_ns`` (stuck between scans, e.g. in idle work): the scan thread is stuck or
    far too slow.

    It wakes every quarter of the watchdog time, so it reacts within 1.25 × watchdog."""

    def __init__(self, scheduler: Scheduler, watchdog_ns: int,
                 trip: Callable[[int], None], clock: Callable[[], int] = time.monotonic_ns
                 ) -> None:
        self.scheduler = scheduler
        self.watchdog_ns = watchdog_ns
        self.trip = trip
        self.clock = clock
        self._stop = threading.Event()
        self._tripped_scan = 0
        self._thread = threading.Thread(target=self._run, name="softplc-watchdog",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def _run(self) -> None:
        period = self.watchdog_ns / 4e9
        sched = self.scheduler
        while not self._stop.wait(period):
            now = self.clock()
            since, beat = sched.scanning_since, sched.last_wake
            if since and now - since > self.watchdog_ns:
                stuck_since = since
            elif beat and now - beat > sched.cycle_ns + self.watchdog_ns:
                stuck_since = beat
            else:
                continue
            if stuck_since == self._tripped_scan:
                continue  # one trip per stuck cycle
            self._tripped_scan = stuck_since
            try:
                self.trip(now - stuck_since)
            except Exception:  # pragma: no cover - the trip must never kill the thread
                log.exception("watchdog trip failed")
