"""When work beside the scan may hold the GIL: between the end of a scan and shortly before
the next one is due (``ScanWindow``). The console's servers and the OPC UA feed use it."""

from __future__ import annotations

import time
from collections.abc import Callable

#: work per round of a serving thread before it looks for I/O again, seconds
ROUND_BUDGET_S = 0.002
#: work stops this long before the next scan is due, until that scan has ended, seconds
#: (at most WINDOW_SHARE of the cycle): the longest console line handled (``stats``,
#: ~1 ms) fits in it with room to spare
QUIET_BEFORE_S = 0.005
WINDOW_SHARE = 0.5
#: the shortest sleep waiting for the next window, seconds
WINDOW_POLL_S = 0.0002


class ScanWindow:
    """When console work may hold the GIL: from the end of a scan until QUIET_BEFORE_S
    (at most half the cycle) before the next one is due, so that the scan thread, waking
    at its deadline, finds the GIL free (a thread holding it delays the scan by up to the
    switch interval). When no scan has ended for two cycles (the scan is stuck, or
    stopped), at any time: the console must still answer."""

    def __init__(self, cycle_s: float, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.cycle_s = cycle_s
        self.clock = clock
        self.sleep = sleep
        #: clock seconds at the end of the last scan (written by the scan thread)
        self.scan_end = 0.0

    def on_scan(self, scan: int) -> None:
        """Scan thread, after each cycle: one float stored."""
        self.scan_end = self.clock()

    def until(self) -> float:
        """Wait for a window; return when it closes (monotonic seconds)."""
        cycle = self.cycle_s
        open_s = cycle - min(WINDOW_SHARE * cycle, QUIET_BEFORE_S)
        while True:
            now = self.clock()
            end = self.scan_end + open_s
            if now < end:
                return end
            if now - self.scan_end > 2 * cycle:
                return now + ROUND_BUDGET_S
            self.sleep(max(WINDOW_POLL_S, self.scan_end + cycle - now))
