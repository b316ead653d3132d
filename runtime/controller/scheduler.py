"""The scan loop: one cycle per absolute deadline ``start + k·cycle`` on the monotonic clock.

Per cycle: sleep until the deadline, run the cycle body (read inputs, scan, write
outputs), record scan time and wake-up lateness, then spend what is left of the period on
the idle work (console requests, noticing state changes, retain hand-off, garbage
collection), never past a guard band before the next deadline. systemd's STATUS= text
(percentiles over thousands of cycles) is built by ``Watchdog``'s thread, not here. A
cycle longer than ``AWAKE_CYCLE_NS`` spends the rest of its wait awake: a request queued
then (a console's, a reload's switch) is served when it comes and the stop ends the wait,
instead of waiting up to a whole cycle (a 1 min cycle would otherwise leave the console
without an answer and make a stop wait a minute).

Overrun policy: when a cycle ends at or after the next deadline, the overrun is counted,
the deadlines it passed are counted as skipped, and the schedule is re-anchored one full
period after the end of the late cycle. There is never a burst of back-to-back catch-up
scans (OpenPLC's behaviour): the process sees one late cycle, then the normal period.

A scan longer than ``watchdog_ns`` is a fault, detected twice: by the loop when the scan
returns, and by ``Watchdog``, a thread that acts while a scan hangs.

Freezes: a process that did not run at all for longer than ``watchdog_ns`` (SIGSTOP, a
paused VM, a suspended system) is noticed when it runs again, as a wake-up later than the
watchdog (CLOCK_MONOTONIC runs on while a process is stopped) or as CLOCK_BOOTTIME
jumping ahead of CLOCK_MONOTONIC (the monotonic clock stands still while the system
sleeps). It is counted in ``ScanStats.freezes`` and reported to ``on_freeze`` before the
cycle's body runs. ``Watchdog`` notices its own freezes too, so that it does not blame the
scan thread for time during which no thread ran, and pings systemd's watchdog.
"""

from __future__ import annotations

import collections
import gc
import logging
import threading
import time
from collections.abc import Callable

from runtime.controller.realtime import make_sleep_until
from runtime.controller.stats import ScanStats

log = logging.getLogger(__name__)

#: idle work stops this long before the next deadline, ns (and never less than a fifth
#: of the period, up to GUARD_MAX_NS)
GUARD_NS = 300_000
#: the longest guard before a deadline, ns: the longest idle item (a console's ``stats``,
#: about 1 ms) fits in it many times
GUARD_MAX_NS = 10_000_000
#: a cycle longer than this spends its wait for the next deadline awake (``serve``): a
#: console request, a reload's switch or the stop is served at once, not a cycle later, ns
AWAKE_CYCLE_NS = 20_000_000
#: young-generation collections run in the idle time once this many objects are pending
GC_GEN0_THRESHOLD = 700
#: the pending-object count is looked at every this many cycles (a few cycles late is
#: harmless; looking costs a call and a tuple)
GC_CHECK_EVERY = 8
#: every this many young collections, the middle generation instead (what survived the
#: young ones since: tuples of tuples are left out of the collector only there, a
#: capture's); more often while middle collections do not fit the idle time (``Scheduler
#: .gc_middle_every``)
GC_MIDDLE_EVERY = 10
#: a full collection at most this often, ns, and only when the idle time allows it
GC_FULL_EVERY_NS = 60_000_000_000
#: a full collection starts only with this many times the last one's time left before
#: the next cycle (the heap grows between two)
GC_FULL_MARGIN = 1.5
#: freezes the watchdog thread remembers for ``Watchdog.froze_during``
FREEZES_KEPT = 8
#: the tuples CPython (3.11) keeps freed for reuse, of each length below
#: FREE_TUPLE_LENGTHS: a full collection frees them all, 0.4 to 1 ms here, whatever the heap
FREE_TUPLES = 2000
FREE_TUPLE_LENGTHS = 20


def fill_free_lists() -> None:
    """Fill the interpreter's free lists of tuples, as a process whose threads make and drop
    tuples keeps them, so that a full collection timed next pays what a later one will: a
    full collection frees every tuple kept for reuse (CPython's ``clear_freelists``). Timed
    right after another collection, with the lists empty, the first estimate was a few µs,
    and the first full collection of a 1 ms cycle overran. Filling them takes about 8 ms,
    once, at start-up."""
    kept = [(x,) * n for n in range(1, FREE_TUPLE_LENGTHS) for x in range(FREE_TUPLES)]
    del kept


def boot_clock_ns() -> int:
    """CLOCK_BOOTTIME, ns: the monotonic clock plus the time the system was suspended."""
    return time.clock_gettime_ns(time.CLOCK_BOOTTIME)


class Scheduler:
    """Paces ``body(now)`` to absolute deadlines; ``run()`` is the scan thread's loop.

    ``idle(deadline_ns)`` is called after each cycle and must return before
    ``deadline_ns``; with a cycle longer than AWAKE_CYCLE_NS, ``serve(deadline_ns)`` is
    called again each time ``wake()`` is (a request queued) until that deadline, and
    ``stop()`` ends the wait at once; ``on_watchdog(scan_ns)`` when a scan took longer than
    the watchdog;
    ``on_freeze(frozen_ns)`` when the process did not run for longer than the watchdog.
    The clocks and the sleep are injectable, so tests run the loop on virtual time
    (``boot_clock`` defaults to CLOCK_BOOTTIME with the default clock, else to none)."""

    def __init__(self, body: Callable[[int], None], cycle_ns: int, watchdog_ns: int, *,
                 idle: Callable[[int], None] | None = None,
                 serve: Callable[[int], None] | None = None,
                 on_watchdog: Callable[[int], None] | None = None,
                 on_freeze: Callable[[int], None] | None = None,
                 clock: Callable[[], int] = time.monotonic_ns,
                 boot_clock: Callable[[], int] | None = None,
                 sleep_until: Callable[[int], None] | None = None,
                 stats: ScanStats | None = None, manage_gc: bool = True) -> None:
        self.body = body
        self.cycle_ns = cycle_ns
        self.watchdog_ns = watchdog_ns
        self.idle = idle
        self.serve = serve
        self.on_watchdog = on_watchdog
        self.on_freeze = on_freeze
        self.clock = clock
        if boot_clock is None and clock is time.monotonic_ns:
            boot_clock = boot_clock_ns
        self.boot_clock = boot_clock
        self.sleep_until = sleep_until or make_sleep_until()
        self.stats = stats or ScanStats()
        self.manage_gc = manage_gc
        self.guard_ns = max(GUARD_NS, min(cycle_ns // 5, GUARD_MAX_NS))
        #: monotonic ns at which the current scan started, 0 between scans (Watchdog reads it)
        self.scanning_since = 0
        #: monotonic ns of the last wake-up, 0 before the first (Watchdog reads it)
        self.last_wake = 0
        #: monotonic ns at which the next cycle is due, set before each idle time (the
        #: console's ScanWindow closes its window a quiet time before it)
        self.due = 0
        self.stop_event = threading.Event()
        self._wake = threading.Event()  # a request queued, or the stop (``serve``)
        self._last_full_gc = 0
        #: young collections run since the last middle one
        self._young = 0
        #: every this many young collections, the middle generation instead: halved (down
        #: to 1) after a middle collection that did not end within the idle time it had,
        #: doubled (up to GC_MIDDLE_EVERY) after one that took a quarter of it or less
        self.gc_middle_every = GC_MIDDLE_EVERY
        #: what the last full collection took, ns: the next one must fit it
        self._full_ns = 0
        #: a full collection is waiting for idle time enough (said once)
        self._full_waits = False
        #: set while another thread builds a large long-lived structure (an online change
        #: preparing its plant): the scan thread collects nothing meanwhile, since a
        #: collection would examine every object just built (tens of ms, once measured
        #: 52 ms, at 100 testers); that thread then freezes them (``gc.freeze()``)
        self.gc_held = False
        #: odd while the scan thread may change the plant's state (a scan, the idle work
        #: after it, a request served in a long cycle's wait), even while it cannot (its
        #: sleep, a garbage collection): a thread that reads the state between two scans
        #: (the feed's image) reads it whole only if ``seq`` is even and the same after
        self.seq = 0

    def wake(self) -> None:
        """A request is queued for ``serve`` (any thread): served now in a long cycle."""
        self._wake.set()

    def stop(self) -> None:
        """End ``run`` after the current cycle, or at once between two (any thread)."""
        self.stop_event.set()
        self._wake.set()

    def run(self, cycles: int | None = None) -> None:
        """Run until ``stop_event`` is set (or ``cycles`` cycles, for tests).

        The per-cycle path is kept lean (it is the controller's fixed cost, paid every
        cycle): bound methods and settings held in locals, the garbage-collection check
        every GC_CHECK_EVERY cycles only, nothing allocated."""
        clock, cycle, stats, body = self.clock, self.cycle_ns, self.stats, self.body
        stop, boot, watchdog = self.stop_event, self.boot_clock, self.watchdog_ns
        sleep_until, idle, record = self.sleep_until, self.idle, stats.record
        on_watchdog, guard, manage_gc = self.on_watchdog, self.guard_ns, self.manage_gc
        stopped = stop.is_set
        awake = self.serve is not None and cycle > AWAKE_CYCLE_NS
        gc_was_enabled = gc.isenabled()
        if manage_gc:
            gc.collect()
            gc.freeze()  # start-up objects (compiled charts, plant) are never scanned again
            gc.disable()
            fill_free_lists()  # as a busy process keeps them: a full collection frees them
            t = clock()
            gc.collect(2)  # what a full collection costs now: the first estimate
            self._full_ns = clock() - t
        deadline = clock()
        self._last_full_gc = deadline
        #: CLOCK_BOOTTIME - CLOCK_MONOTONIC at the last wake-up: grows by each suspend
        slept = 0 if boot is None else boot() - deadline
        n = 0
        last = -1 if cycles is None else cycles
        try:
            while n != last and not stopped():
                sleep_until(deadline)
                self.seq += 1  # odd: the state may change from here (a freeze latched too)
                wake = clock()
                frozen = wake - deadline
                if boot is not None:
                    was, slept = slept, boot() - wake
                    frozen += slept - was
                if frozen > watchdog:
                    self._froze(frozen)
                self.scanning_since = self.last_wake = wake
                body(wake)
                end = clock()
                self.scanning_since = 0
                scan = end - wake
                record(scan, wake - deadline)
                n += 1
                if scan > watchdog and on_watchdog is not None:
                    on_watchdog(scan)
                deadline += cycle
                if end >= deadline:
                    stats.overruns += 1
                    stats.skipped += (end - deadline) // cycle
                    deadline = end + cycle
                self.due = deadline
                if idle is not None:
                    idle(deadline - guard)
                self.seq += 1  # even: nothing changes the state until the next bump
                if manage_gc and not n % GC_CHECK_EVERY:
                    self._collect(deadline - guard)
                if awake:
                    self._serve_until(deadline - guard)
        finally:
            self.seq += self.seq & 1  # even: stopped
            self.scanning_since = self.last_wake = 0
            if manage_gc:
                gc.unfreeze()
                if gc_was_enabled:
                    gc.enable()

    def _serve_until(self, until: int) -> None:
        """Wait awake until monotonic ``until``: ``serve`` each time ``wake()`` is called,
        back at once on ``stop()``. (The exact sleep to the deadline follows.)"""
        clock, wake, stopped, serve = self.clock, self._wake, self.stop_event.is_set, self.serve
        assert serve is not None
        while not stopped():
            left = until - clock()
            if left <= 0 or not wake.wait(left / 1e9):
                return
            wake.clear()  # before serving: a request queued meanwhile sets it again
            if not stopped():
                self.seq += 1
                serve(until)
                self.seq += 1

    def _froze(self, frozen: int) -> None:
        self.stats.record_freeze(frozen)
        if self.on_freeze is not None:
            self.on_freeze(frozen)

    def _collect(self, until: int) -> None:
        """Garbage collection in the idle part of the cycle only (none while
        ``gc_held``): a young collection when objects are pending (every
        ``gc_middle_every``-th one the middle generation too), a full one once a
        minute if the last full one's time (times GC_FULL_MARGIN) fits before ``until``,
        else the middle generation then (what survived since: a minute's worth at most)
        and the full one waits for a cycle with idle time enough."""
        if self.gc_held or gc.get_count()[0] < GC_GEN0_THRESHOLD:
            return
        stats = self.stats
        t0 = self.clock()
        if t0 >= until:
            return  # no idle time left: try after the next cycle
        if t0 - self._last_full_gc < GC_FULL_EVERY_NS:
            self._young += 1
            if self._young < self.gc_middle_every:
                gc.collect(0)
            else:
                self._young = 0
                gc.collect(1)
                self._pace_middle(self.clock() - t0, until - t0)
        elif until - t0 >= self._full_ns * GC_FULL_MARGIN:
            self._full(t0)
        else:
            self._last_full_gc = t0  # tried again in a minute
            stats.gc_full_deferred += 1
            if not self._full_waits:
                self._full_waits = True
                log.warning(
                    "a full garbage collection took %.1f ms, too long for the idle time "
                    "left in a cycle (%.1f ms): it waits for a cycle with idle time enough; the "
                    "younger generations are collected meanwhile, long-lived cyclic "
                    "garbage is not (stats: gc_full_deferred)",
                    self._full_ns / 1e6, (until - t0) / 1e6)
            gc.collect(1)
        stats.gc_runs += 1
        stats.gc_ns += self.clock() - t0

    def _pace_middle(self, took: int, had: int) -> None:
        """After a middle collection that took ``took`` ns of the ``had`` ns of idle time
        left when it started. It examines what survived the young collections since the
        last one: one that did not end in time makes the next ones come twice as often
        (each then examines what survived half as many), down to every young one; one
        that took a quarter of that time or less, half as often again."""
        every = self.gc_middle_every
        if took > had:
            every = max(1, every // 2)
        elif 4 * took <= had:
            every = min(GC_MIDDLE_EVERY, 2 * every)
        if every != self.gc_middle_every:
            log.debug("a middle collection took %.2f ms of %.2f ms of idle time: one every "
                      "%d young ones now", took / 1e6, had / 1e6, every)
            self.gc_middle_every = every

    def _full(self, t0: int) -> None:
        """A full collection started at ``t0``, timed: the next one must fit that (counted
        in ``gc_runs`` by the caller)."""
        gc.collect(2)
        took = self.clock() - t0
        stats = self.stats
        self._last_full_gc = t0
        self._full_waits = False
        self._full_ns = stats.gc_full_last = took
        stats.gc_full_max = max(stats.gc_full_max, took)
        stats.gc_full_runs += 1


class Watchdog:
    """A thread that watches the scan thread of ``scheduler`` and feeds systemd's watchdog.

    It calls ``trip(running_ns)`` once when a scan has been running longer than
    ``watchdog_ns``, or the loop has not woken up for a cycle plus ``watchdog_ns`` (stuck
    between scans, e.g. in idle work): the scan thread is stuck or far too slow. It wakes
    every quarter of the watchdog time, so it reacts within 1.25 × watchdog.

    ``ping()`` (systemd's WATCHDOG=1) is called every ``ping_interval_ns`` while the scan
    loop runs and is not stuck, whatever the cycle time: only a stuck scan thread (or a
    stopped loop) starves systemd's watchdog.

    When the thread itself did not run for longer than the watchdog, the whole process was
    frozen: that is counted (``freezes``), remembered for ``froze_during`` and not blamed
    on the scan thread, which gets a full watchdog time from the resumption to wake up.

    ``status()`` (the work behind systemd's STATUS=: percentiles over thousands of cycles)
    runs in this thread, never in the scan thread: every ``status_interval_ns``, and soon
    after ``request_status()`` (which the scan thread calls when its state changes).
    ``stop_pinging()`` ends it too."""

    def __init__(self, scheduler: Scheduler, watchdog_ns: int,
                 trip: Callable[[int], None], clock: Callable[[], int] = time.monotonic_ns,
                 *, ping: Callable[[], object] | None = None, ping_interval_ns: int = 0,
                 status: Callable[[], object] | None = None, status_interval_ns: int = 0
                 ) -> None:
        self.scheduler = scheduler
        self.watchdog_ns = watchdog_ns
        self.trip = trip
        self.clock = clock
        #: longest wait between two looks, ns
        self.period_ns = max(1, watchdog_ns // 4)
        self.ping_interval_ns = ping_interval_ns
        self._ping = ping if ping_interval_ns > 0 else None
        self._ping_lock = threading.Lock()
        self._next_ping = 0
        self.status_interval_ns = status_interval_ns
        self._status = status
        self._next_status = 0
        self._status_due = False
        self._wake = threading.Event()  # stop() or request_status()
        #: freezes of the whole process this thread noticed
        self.freezes = 0
        #: (resumed at, frozen for) of the last freezes, monotonic ns
        self._frozen: collections.deque[tuple[int, int]] = collections.deque(
            maxlen=FREEZES_KEPT)
        self._last_tick = 0
        self._resumed = 0
        self._stop = threading.Event()
        self._tripped_scan = 0
        self._thread = threading.Thread(target=self._run, name="softplc-watchdog",
                                        daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self.stop_pinging()
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def stop_pinging(self) -> None:
        """No ping leaves after this returns (the stop: STOPPING=1 is the last word)."""
        with self._ping_lock:
            self._ping = self._status = None

    def request_status(self) -> None:
        """Have ``status()`` run soon in this thread (from the scan thread: a flag and an
        event set, no formatting)."""
        self._status_due = True
        self._wake.set()

    def froze_during(self, start: int, end: int) -> int:
        """How long the process was frozen between monotonic ``start`` and ``end`` (ns),
        as far as this thread can tell: a freeze it noticed, or its own silence since
        before ``start`` (it has not run since the process resumed); 0 if none."""
        for resumed, frozen in reversed(self._frozen):
            if start < resumed <= end + self.period_ns:
                return frozen
        silent = end - self._last_tick
        if self._last_tick and self._last_tick < start and \
                silent > self.period_ns + self.watchdog_ns:
            return silent - self.period_ns
        return 0

    def _run(self) -> None:
        clock = self.clock
        self._last_tick = clock()
        self._next_status = self._last_tick + self.status_interval_ns
        while True:
            wait = self.period_ns
            now = clock()
            if self._ping is not None:
                wait = min(wait, max(0, self._next_ping - now))
            if self._status is not None and self.status_interval_ns > 0:
                wait = min(wait, max(0, self._next_status - now))
            self._wake.wait(wait / 1e9)
            self._wake.clear()
            if self._stop.is_set():
                return
            now = clock()
            try:
                self.tick(now)
            except Exception:  # pragma: no cover - the thread must never die
                log.exception("watchdog check failed")
            self.report(now)

    def report(self, now: int) -> None:
        """Run ``status()`` if it is due (requested, or its interval has passed)."""
        if self._status is None or not (
                self._status_due or
                (self.status_interval_ns > 0 and now >= self._next_status)):
            return
        self._status_due = False
        self._next_status = now + self.status_interval_ns
        try:
            with self._ping_lock:
                if self._status is not None:
                    self._status()
        except Exception:  # pragma: no cover - the thread must never die
            log.exception("status report failed")

    def tick(self, now: int) -> None:
        """One look at the scan thread at monotonic ``now``: trip, ping, or nothing."""
        last, self._last_tick = self._last_tick, now
        if last and now - last > self.period_ns + self.watchdog_ns:
            # this thread did not run either: the process was frozen, not the scan stuck
            self.freezes += 1
            self._frozen.append((now, now - last - self.period_ns))
            self._resumed = now
            return
        sched = self.scheduler
        since, beat = sched.scanning_since, sched.last_wake
        if not beat:
            return  # the loop is not running: nothing to judge, nothing to vouch for
        if since and now - max(since, self._resumed) > self.watchdog_ns:
            stuck_since = since
        elif now - max(beat, self._resumed) > sched.cycle_ns + self.watchdog_ns:
            stuck_since = beat
        else:
            # after a freeze, vouch for the scan thread only once it has woken since
            if self._ping is not None and now >= self._next_ping and beat >= self._resumed:
                with self._ping_lock:
                    if self._ping is not None:
                        self._ping()
                self._next_ping = now + self.ping_interval_ns
            return
        if stuck_since == self._tripped_scan:
            return  # one trip per stuck cycle
        self._tripped_scan = stuck_since
        try:
            self.trip(now - stuck_since)
        except Exception:  # pragma: no cover - the trip must never kill the thread
            log.exception("watchdog trip failed")
