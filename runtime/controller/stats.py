"""Cycle statistics of the scan loop: scan time and wake-up lateness, in a fixed-size store.

``record()`` runs once per cycle in the scan thread: a few integer stores into
preallocated arrays, no container grows. Percentiles are computed on demand, off the hot
path, over the last ``window`` cycles; min, mean, max and the overrun count cover the
whole run.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from typing import Any

#: cycles kept for percentiles (p99.9 needs at least 1000)
WINDOW = 8192


@dataclass(frozen=True, slots=True)
class Summary:
    """Statistics of one measured quantity, in ns."""

    last: int
    min: int
    mean: float
    p50: int
    p99: int
    p999: int
    max: int

    def as_dict(self, scale: float = 1e-3) -> dict[str, float]:
        """The figures divided by ``scale`` ns (default: µs), rounded to 0.1."""
        return {k: round(getattr(self, k) * scale, 1)
                for k in ("last", "min", "mean", "p50", "p99", "p999", "max")}


def _percentile(sorted_values: list[int], q: float) -> int:
    if not sorted_values:
        return 0
    i = min(len(sorted_values) - 1, max(0, int(round(q * (len(sorted_values) - 1)))))
    return sorted_values[i]


class ScanStats:
    """Scan time and lateness of every cycle, overruns, freezes of the process, and
    idle-time garbage collections."""

    def __init__(self, window: int = WINDOW) -> None:
        self.window = window
        self._scan = array("q", bytes(8 * window))
        self._late = array("q", bytes(8 * window))
        self.reset()

    def reset(self) -> None:
        """Forget everything (e.g. after start-up, so compilation does not count)."""
        self.count = 0
        self.overruns = 0
        self.skipped = 0  # deadlines passed over by re-anchoring after overruns
        self.gc_runs = 0
        self.gc_ns = 0
        self.freezes = 0  # times the process did not run for longer than the watchdog
        self.freeze_max = 0  # the longest such time, ns
        self.scan_last = self.late_last = 0
        self.scan_min = self.late_min = 1 << 62
        self.scan_max = self.late_max = 0
        self.scan_sum = self.late_sum = 0

    def record(self, scan_ns: int, late_ns: int) -> None:
        """One cycle: how long the scan took and how late it started (ns)."""
        i = self.count % self.window
        self._scan[i] = scan_ns
        self._late[i] = late_ns
        self.count += 1
        self.scan_last = scan_ns
        self.late_last = late_ns
        self.scan_sum += scan_ns
        self.late_sum += late_ns
        if scan_ns < self.scan_min:
            self.scan_min = scan_ns
        if scan_ns > self.scan_max:
            self.scan_max = scan_ns
        if late_ns < self.late_min:
            self.late_min = late_ns
        if late_ns > self.late_max:
            self.late_max = late_ns

    def record_freeze(self, frozen_ns: int) -> None:
        """The process did not run for ``frozen_ns`` (SIGSTOP, a paused VM, a suspend)."""
        self.freezes += 1
        if frozen_ns > self.freeze_max:
            self.freeze_max = frozen_ns

    def _summary(self, ring: array[int], last: int, lo: int, hi: int, total: int) -> Summary:
        n = min(self.count, self.window)
        values = sorted(ring[:n])
        mean = total / self.count if self.count else 0.0
        return Summary(last, lo if self.count else 0, mean, _percentile(values, 0.5),
                       _percentile(values, 0.99), _percentile(values, 0.999), hi)

    def scan(self) -> Summary:
        return self._summary(self._scan, self.scan_last, self.scan_min, self.scan_max,
                             self.scan_sum)

    def lateness(self) -> Summary:
        return self._summary(self._late, self.late_last, self.late_min, self.late_max,
                             self.late_sum)

    def as_dict(self) -> dict[str, Any]:
        """Everything, times in µs (what ``stats`` on the console shows)."""
        return {"cycles": self.count, "overruns": self.overruns, "skipped": self.skipped,
                "scan_us": self.scan().as_dict(), "lateness_us": self.lateness().as_dict(),
                "gc_runs": self.gc_runs, "gc_ms": round(self.gc_ns / 1e6, 2),
                "freezes": self.freezes, "freeze_max_ms": round(self.freeze_max / 1e6, 1)}
