"""Cycle statistics of the scan loop: scan time and wake-up lateness, in a fixed-size store.

``record()`` runs once per cycle in the scan thread: a few integer stores into
preallocated arrays, no container grows, nothing is allocated. Percentiles are computed on
demand, off the hot path, over the last ``window`` cycles; min, mean, max and the overrun
count cover the whole run. ``p99()`` (systemd's STATUS= line) finds the two p99 figures
without sorting a whole window in one call: another thread computing it never holds the
GIL for more than a chunk's sort (~50 µs), so the scan thread is never stalled by it.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from typing import Any

#: cycles kept for percentiles (p99.9 needs at least 1000)
WINDOW = 8192
#: values sorted per call by ``p99()``: the longest the GIL is held at once
CHUNK = 512


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


def _rank(n: int, q: float) -> int:
    """Index of the ``q`` quantile in ``n`` sorted values."""
    return min(n - 1, max(0, int(round(q * (n - 1)))))


def _percentile(sorted_values: list[int], q: float) -> int:
    if not sorted_values:
        return 0
    return sorted_values[_rank(len(sorted_values), q)]


def high_percentile(values: array[int], n: int, q: float) -> int:
    """The ``q`` quantile (q >= 0.5) of ``values[:n]``, equal to ``_percentile`` of the
    sorted values, found from the top ``k`` of each CHUNK-sized slice: no single call
    sorts more than CHUNK values (or the k * chunks candidates)."""
    if n <= 0:
        return 0
    k = n - _rank(n, q)  # the answer is the k-th largest value
    top: list[int] = []
    for start in range(0, n, CHUNK):
        chunk = sorted(values[start:min(n, start + CHUNK)])
        top += chunk[-k:]
    top.sort()
    return top[-k]


class ScanStats:
    """Scan time and lateness of every cycle, overruns, freezes of the process, and
    idle-time garbage collections."""

    def __init__(self, window: int = WINDOW) -> None:
        self.window = window
        self._scan = array("q", bytes(8 * window))
        self._late = array("q", bytes(8 * window))
        #: ``count & _mask`` is the ring index when the window is a power of two
        self._mask = window - 1 if window & (window - 1) == 0 else -1
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
        self.scan_min = self.late_min = 1 << 62
        self.scan_max = self.late_max = 0
        self.scan_sum = self.late_sum = 0

    def record(self, scan_ns: int, late_ns: int) -> None:
        """One cycle: how long the scan took and how late it started (ns)."""
        n = self.count
        i = n & self._mask if self._mask >= 0 else n % self.window
        self._scan[i] = scan_ns
        self._late[i] = late_ns
        self.count = n + 1
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

    @property
    def scan_last(self) -> int:
        """The last cycle's scan time, ns (0 before the first)."""
        return self._scan[(self.count - 1) % self.window] if self.count else 0

    @property
    def late_last(self) -> int:
        """The last cycle's wake-up lateness, ns (0 before the first)."""
        return self._late[(self.count - 1) % self.window] if self.count else 0

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

    def p99(self) -> tuple[int, int]:
        """(scan p99, lateness p99) over the window, ns, as ``scan()`` and ``lateness()``
        give them, never holding the GIL for a whole window's sort (safe to call from
        another thread while the scan runs; a cycle recorded meanwhile may count or not)."""
        n = min(self.count, self.window)
        return (high_percentile(self._scan, n, 0.99), high_percentile(self._late, n, 0.99))

    def as_dict(self) -> dict[str, Any]:
        """Everything, times in µs (what ``stats`` on the console shows)."""
        return {"cycles": self.count, "overruns": self.overruns, "skipped": self.skipped,
                "scan_us": self.scan().as_dict(), "lateness_us": self.lateness().as_dict(),
                "gc_runs": self.gc_runs, "gc_ms": round(self.gc_ns / 1e6, 2),
                "freezes": self.freezes, "freeze_max_ms": round(self.freeze_max / 1e6, 1)}
