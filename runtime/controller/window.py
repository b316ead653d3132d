"""When work beside the scan may hold the GIL, and how much of it: between the end of a
scan and shortly before the next one is due, within a share of the processor time
(``ScanWindow``). The console's servers and the OPC UA feed use it."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

#: work per round of a serving thread before it looks for I/O again, seconds
ROUND_BUDGET_S = 0.002
#: work stops this long before the next scan is due, until that scan has ended, seconds
#: (at most WINDOW_SHARE of the cycle): a console line handled takes far less
#: (``stats`` ~10 µs, ``get`` of every name of a plant ~1 ms)
QUIET_BEFORE_S = 0.005
WINDOW_SHARE = 0.5
#: the shortest sleep waiting for the processor budget, seconds
WINDOW_POLL_S = 0.0002
#: no scan ended for this long (or two cycles, if longer): the scan is stuck or stopped,
#: and work goes on at any time, seconds. Not less: a scan merely late on a busy machine
#: must find the GIL free when it finally runs
STALE_S = 0.5
#: the longest a thread waits for the end of a scan before it looks again, seconds
WAIT_MAX_S = 1.0
#: ``pause()`` inside a window sleeps this long, seconds
PAUSE_S = 0.0001
#: processor time the threads that ``spend`` from one window may use together, as a share
#: of the time that passes: a flood of requests, however costly each one, never holds
#: the GIL more than that...
CPU_SHARE = 0.1
#: ...and at once: CPU_SHARE of a cycle, at least the first, at most the second, seconds
CPU_BURST_S = 0.0005
CPU_BURST_MAX_S = 0.010


@dataclass(frozen=True, slots=True)
class Slot:
    """Where a thread may work now (clock seconds): until ``closes``; and wait (for
    input, for its budget) inside it only until ``settles``, a quiet time before it
    closes. After that, what is not done waits for the next window."""

    closes: float
    settles: float


class ScanWindow:
    """When work beside the scan may hold the GIL: from the end of a scan until
    QUIET_BEFORE_S (at most half the cycle) before the next one is due, so that the scan
    thread, waking at its deadline, finds the GIL free (a thread holding it delays the
    scan by up to the switch interval, and by as long as the OS keeps that thread off
    the processor). The window closes before the *next deadline*, not a cycle after the
    last scan ended: a scan that ended late leaves a shorter window, never a quiet time
    eaten into. When no scan has ended for STALE_S (or two cycles, if longer: the scan is
    stuck, or stopped), at any time: the console must still answer.

    The work comes right after the scan, in one stretch: a thread may wait (for input,
    for its budget) inside a window only until a second quiet time before it closes
    (``Slot.settles``). At a 10 ms cycle that is never: each thread does what there is
    and then sleeps until the next scan has ended, so on a busy machine that keeps it
    off the processor while it holds the GIL, the OS has the most time to run it again
    before the next scan (it has no way of knowing that the scan waits for it). Between
    two windows a thread waits for the end of the next scan (an Event set by
    ``on_scan``): it is never woken while the scan runs.

    The threads that report their work (``spend``, processor seconds) share a budget of
    CPU_SHARE of the time, at most CPU_SHARE of a cycle at once (within CPU_BURST_S and
    CPU_BURST_MAX_S): whatever the clients ask, that work takes at most a tenth of a
    processor and the GIL, and only inside the windows (also while the scan is stuck,
    when a slot is always open). A thread that never spends (the OPC UA feed) only
    keeps to the windows."""

    def __init__(self, cycle_s: float, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep,
                 due: Callable[[], float] | None = None, share: float = CPU_SHARE,
                 wait: Callable[[float], object] | None = None) -> None:
        self.cycle_s = cycle_s
        self.clock = clock
        self.sleep = sleep
        self._ended = threading.Event()  # set by on_scan
        #: waits (at most the given seconds) for the end of a scan
        self.wait = wait if wait is not None else self._ended.wait
        #: clock seconds at which the next scan is due (Daemon.next_scan_due), read
        #: after each scan; without it, a cycle after the last scan's end
        self.due = due
        self.quiet_s = min(WINDOW_SHARE * cycle_s, QUIET_BEFORE_S)
        #: clock seconds at the end of the last scan (written by the scan thread)
        self.scan_end = 0.0
        #: clock seconds at which the window after the last scan closes (idem)
        self.closes = 0.0
        self.share = share
        self.burst_s = min(CPU_BURST_MAX_S, max(CPU_BURST_S, share * cycle_s))
        self._closed = False
        self._lock = threading.Lock()
        self._tokens = self.burst_s
        self._filled = clock()

    def on_scan(self, scan: int) -> None:
        """Scan thread, after each cycle: two floats stored, an Event set."""
        now = self.clock()
        due = self.due() if self.due is not None else 0.0
        if due <= now:  # not known (or a deadline passed already): a cycle from now
            due = now + self.cycle_s
        self.closes = due - self.quiet_s
        self.scan_end = now
        self._ended.set()

    def until(self) -> float:
        """Wait for a window with budget left; return when it closes (clock seconds)."""
        return self.slot().closes

    def slot(self) -> Slot:
        """Wait for a window with budget left, and return it. After ``close()``, at once
        (a slot closed already)."""
        stale = max(2 * self.cycle_s, STALE_S)
        spent_in = -1.0  # the scan end of a window whose rest is not used
        while True:
            now = self.clock()
            if self._closed:
                return Slot(now, now)
            if now < self.closes and self.scan_end != spent_in:
                slot = Slot(self.closes, self.closes - self.quiet_s)
            elif now - self.scan_end > stale:
                slot = Slot(now + ROUND_BUDGET_S, now + ROUND_BUDGET_S)
            else:
                self._next_scan(now, stale)
                continue
            short = self._shortfall(now)
            if short <= 0.0:
                return slot
            back = now + short / self.share  # the budget comes back at ``share`` s/s
            if back <= slot.settles:
                self.sleep(max(WINDOW_POLL_S, back - now))
            elif slot.settles < slot.closes:  # not in this window: in the next one
                spent_in = self.scan_end
            else:  # the scan is stuck: no window to wait for
                self.sleep(max(WINDOW_POLL_S, back - now))

    def pause(self) -> None:
        """Between two slices of a long piece of work (the percentiles of ``stats``): a
        short sleep (the GIL free, the thread never running for long at a stretch), or,
        once this window has closed, until the next one opens: such work is done in
        pieces, inside the windows, never across a scan's deadline."""
        now = self.clock()
        if now < self.closes or self._closed:
            self.sleep(PAUSE_S)
            return
        stale = max(2 * self.cycle_s, STALE_S)
        while not self._closed and now >= self.closes and now - self.scan_end <= stale:
            self._next_scan(now, stale)
            now = self.clock()

    def _next_scan(self, now: float, stale: float) -> None:
        """Wait for the end of the next scan (at most until the scan counts as stuck)."""
        seen = self.scan_end
        self._ended.clear()
        if self.scan_end == seen and not self._closed:  # (none ended since it was read)
            self.wait(min(WAIT_MAX_S, max(WINDOW_POLL_S, seen + stale - now)))

    def close(self) -> None:
        """The threads using this window are stopping: ``until`` returns at once."""
        self._closed = True
        self._ended.set()

    def spend(self, cpu_s: float) -> bool:
        """``cpu_s`` seconds of processor time were used (any thread, any time); whether
        some budget is left."""
        with self._lock:
            self._tokens -= max(0.0, cpu_s)
            return self._tokens > 0.0

    def meter(self) -> CpuMeter:
        """A meter of the calling thread's processor time, spent from this window."""
        return CpuMeter(self)

    def _shortfall(self, now: float) -> float:
        """Processor seconds missing before work may go on (<= 0: none missing)."""
        with self._lock:
            self._tokens = min(self.burst_s,
                               self._tokens + (now - self._filled) * self.share)
            self._filled = now
            return -self._tokens if self._tokens <= 0.0 else 0.0


class CpuMeter:
    """The processor time of the thread that made it (``time.thread_time``: its own, not
    the time it waits for I/O or the scan), spent from a ScanWindow's budget."""

    def __init__(self, window: ScanWindow) -> None:
        self.window = window
        self._last = time.thread_time()

    def charge(self) -> bool:
        """Spend this thread's processor time since the last charge; whether some budget
        is left."""
        now = time.thread_time()
        used, self._last = now - self._last, now
        return self.window.spend(used)
