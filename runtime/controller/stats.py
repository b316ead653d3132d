"""Cycle statistics of the scan loop: scan time and wake-up lateness, in a fixed-size store.

``record()`` runs once per cycle in the scan thread: a few integer stores into
preallocated arrays, no container grows, nothing is allocated. Percentiles are computed on
demand, off the hot path, over the last ``window`` cycles; min, mean, max and the overrun
count cover the whole run. They are found without sorting a whole window in one call
(``percentiles``): the thread computing them (the watchdog's for systemd's STATUS= line,
the console's for ``stats``, the feed's for its status) never holds the GIL for more than
a chunk's sort (~50 µs), so the scan thread is never stalled by it; and a chunk is sorted
once, not at every call (``ScanStats._chunks``).
"""

from __future__ import annotations

from array import array
from bisect import bisect_left, bisect_right
from collections.abc import Callable
from dataclasses import dataclass
from itertools import chain
from typing import Any

#: cycles kept for percentiles (p99.9 needs at least 1000)
WINDOW = 8192
#: values sorted per call by ``percentiles``: the longest the GIL is held at once
CHUNK = 512
#: values sorted at most to read a quantile among them, once found to lie in their range
#: (no more than a chunk: the same longest hold of the GIL)
SELECTED = CHUNK


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


#: quantiles of a window: median, p99, p99.9
QUANTILES = (0.5, 0.99, 0.999)


def _sort(values: array[int]) -> array[int]:
    """``values`` sorted, as an array: kept between calls, and the garbage collector has
    nothing to follow in it (a list of ints would be one more reference per value)."""
    return array("q", sorted(values))


def _count_le(chunks: list[array[int]], v: int) -> int:
    """How many values of the sorted ``chunks`` are at most ``v``."""
    return sum(bisect_right(c, v) for c in chunks)


def _select(chunks: list[array[int]], n: int, qs: tuple[float, ...],
            pause: Callable[[], object] | None = None) -> list[int]:
    """The ``qs`` quantiles of the ``n`` values in the sorted ``chunks`` (as
    ``percentiles``). For each, a range of values known to hold it: the chunks' own
    quantiles at ``q`` (confirmed by two counts with ``bisect``, else every value),
    halved while it holds more than SELECTED values (a count per step, ~4 µs for 16
    chunks); then the values in the range, taken from each chunk, are sorted and the
    quantile read among them. ``pause``, as for ``percentiles``, between two
    quantiles."""
    if n <= 0:
        return [0] * len(qs)
    out: list[int] = []
    for q in qs:
        if out and pause is not None:
            pause()
        need = _rank(n, q) + 1  # the quantile is the need-th smallest value
        lo = min(c[_rank(len(c), q)] for c in chunks)
        hi = max(c[_rank(len(c), q)] for c in chunks)
        below = _count_le(chunks, lo - 1)  # values < lo
        upto = _count_le(chunks, hi)  # values <= hi
        if not below < need <= upto:
            lo, hi = min(c[0] for c in chunks), max(c[-1] for c in chunks)
            below, upto = 0, n
        while upto - below > SELECTED and lo < hi:
            mid = (lo + hi) // 2
            k = _count_le(chunks, mid)
            if k >= need:
                hi, upto = mid, k
            else:
                lo, below = mid + 1, k
        if lo == hi:
            out.append(lo)
            continue
        between = sorted(chain.from_iterable(c[bisect_left(c, lo):bisect_right(c, hi)]
                                             for c in chunks))
        out.append(between[need - below - 1])
    return out


def percentiles(values: array[int], n: int, qs: tuple[float, ...],
                pause: Callable[[], object] | None = None) -> list[int]:
    """The ``qs`` quantiles of ``values[:n]``: for each, the value at ``_rank(n, q)`` of
    the sorted values, found without one call holding the GIL for a whole sort. Each
    CHUNK-sized slice is sorted on its own (~50 µs a call), then the quantiles are
    selected from the sorted slices (``_select``). 0 when there are no values.
    ``pause()`` is called after each slice's sort: a thread that sleeps there
    (``time.sleep``) never runs for long at a stretch, so a busy machine does not take the
    processor from it while it holds the GIL (the scan thread would wait for it). A
    ``ScanStats`` keeps its window's sorted slices between calls (``_chunks``)."""
    return _select(_sorted_chunks(values, n, pause), n, qs, pause)


def _sorted_chunks(values: array[int], n: int, pause: Callable[[], object] | None
                   ) -> list[array[int]]:
    """``values[:n]`` in sorted CHUNK-sized slices, ``pause()`` after each sort."""
    chunks = []
    for start in range(0, max(0, n), CHUNK):
        chunks.append(_sort(values[start:min(n, start + CHUNK)]))
        if pause is not None:
            pause()
    return chunks


class ScanStats:
    """Scan time and lateness of every cycle, overruns, freezes of the process, and
    idle-time garbage collections."""

    def __init__(self, window: int = WINDOW) -> None:
        self.window = window
        self._scan = array("q", bytes(8 * window))
        self._late = array("q", bytes(8 * window))
        #: ``count & _mask`` is the ring index when the window is a power of two
        self._mask = window - 1 if window & (window - 1) == 0 else -1
        #: sorted copies of the rings' complete chunks, by the chunk's number since the
        #: last reset (``_chunks``); a window that is not a whole number of chunks keeps
        #: none
        self._sorted: tuple[dict[int, array[int]], dict[int, array[int]]] = ({}, {})
        self.reset()

    def reset(self) -> None:
        """Forget everything (e.g. after start-up, so compilation does not count). Never
        on a running daemon's: its listeners (the feed, the alarm board) are given
        ``count`` as the scan number and pace themselves on it; a reset stops them until
        the count comes back where it was."""
        self.count = 0
        # new dicts, not cleared ones: a thread computing percentiles meanwhile keeps
        # what it sorts in the old ones
        self._sorted = ({}, {})
        self.overruns = 0
        self.skipped = 0  # deadlines passed over by re-anchoring after overruns
        self.gc_runs = 0
        self.gc_ns = 0
        #: the last full collection's time, ns (what the next must fit in), and the
        #: longest
        self.gc_full_last = self.gc_full_max = 0
        #: full collections run in the idle time, and those due that waited (the idle
        #: time too short for one)
        self.gc_full_runs = self.gc_full_deferred = 0
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

    def _summary(self, ring: array[int], last: int, lo: int, hi: int, total: int,
                 quantiles: list[int] | None = None) -> Summary:
        if quantiles is None:
            quantiles = self._quantiles(ring, QUANTILES)
        p50, p99, p999 = quantiles
        mean = total / self.count if self.count else 0.0
        return Summary(last, lo if self.count else 0, mean, p50, p99, p999, hi)

    def scan(self, quantiles: list[int] | None = None) -> Summary:
        """Scan time; its quantiles computed now, or ``quantiles`` (as computed by
        ``window_quantiles``)."""
        return self._summary(self._scan, self.scan_last, self.scan_min, self.scan_max,
                             self.scan_sum, quantiles)

    def lateness(self, quantiles: list[int] | None = None) -> Summary:
        """Wake-up lateness; as ``scan``."""
        return self._summary(self._late, self.late_last, self.late_min, self.late_max,
                             self.late_sum, quantiles)

    def window_quantiles(self, pause: Callable[[], object] | None = None
                         ) -> tuple[list[int], list[int]]:
        """QUANTILES of the scan times and of the lateness over the window, ns (the
        expensive part of the figures: ``pause`` as for ``percentiles``)."""
        return (self._quantiles(self._scan, QUANTILES, pause),
                self._quantiles(self._late, QUANTILES, pause))

    def lateness_quantiles(self, pause: Callable[[], object] | None = None) -> list[int]:
        """QUANTILES of the lateness over the window, ns, for ``lateness`` (``pause`` as
        for ``percentiles``)."""
        return self._quantiles(self._late, QUANTILES, pause)

    def p99(self, pause: Callable[[], object] | None = None) -> tuple[int, int]:
        """(scan p99, lateness p99) over the window, ns, as ``scan()`` and ``lateness()``
        give them (safe to call from another thread while the scan runs; a cycle
        recorded meanwhile may count or not; ``pause`` as for ``percentiles``)."""
        return (self._quantiles(self._scan, (0.99,), pause)[0],
                self._quantiles(self._late, (0.99,), pause)[0])

    def _quantiles(self, ring: array[int], qs: tuple[float, ...],
                   pause: Callable[[], object] | None = None) -> list[int]:
        """The ``qs`` quantiles of ``ring`` (``_scan`` or ``_late``) over the window, as
        ``percentiles`` finds them, from the window's sorted chunks (``_chunks``)."""
        chunks, n = self._chunks(ring, pause)
        return _select(chunks, n, qs, pause)

    def _chunks(self, ring: array[int], pause: Callable[[], object] | None
                ) -> tuple[list[array[int]], int]:
        """The window of ``ring`` in sorted CHUNK-sized slices, and how many values they
        hold. A chunk is numbered by the cycles it holds (chunk ``s``: cycles ``s *
        CHUNK`` to ``(s + 1) * CHUNK - 1`` since the last reset); once complete it is
        sorted once and kept until the ring writes over it, so a call sorts only the
        chunks completed since the last (at a 1 ms cycle, two a second) and the one
        being written, which also holds the window's oldest cycles (pause: as for
        ``percentiles``, after each sort). A cycle recorded meanwhile may count or not,
        as for ``percentiles``. A chunk that the ring wrote over while it was copied
        (the scan goes on meanwhile) is kept under a number that no later window holds:
        only the count that passed it could write over it."""
        window = self.window
        count = self.count
        if window % CHUNK:  # chunks that do not stay put: sorted at every call
            n = min(count, window)
            return _sorted_chunks(ring, n, pause), n
        kept = self._sorted[ring is self._late]
        per = window // CHUNK  # chunks in the window
        head = count // CHUNK  # the chunk being written (none yet if count % CHUNK == 0)
        first = max(0, head - per + (1 if count % CHUNK else 0))  # oldest complete one
        chunks = []
        for s in range(first, head):  # oldest first: the first the ring writes over
            c = kept.get(s)
            if c is None:
                start = (s % per) * CHUNK
                c = kept[s] = _sort(ring[start:start + CHUNK])
                if pause is not None:
                    pause()
            chunks.append(c)
        for s in list(kept):  # (one copy: other threads may add to it meanwhile)
            if s < first:
                kept.pop(s, None)
        if count % CHUNK:
            start = (head % per) * CHUNK
            chunks.append(_sort(ring[start:start + (CHUNK if count >= window
                                                      else count - head * CHUNK)]))
            if pause is not None:
                pause()
        return chunks, min(count, window)

    def as_dict(self, quantiles: tuple[list[int], list[int]] | None = None
                ) -> dict[str, Any]:
        """Everything, times in µs (what ``stats`` on the console shows); the quantiles
        computed now, or ``quantiles`` (``window_quantiles``, computed earlier)."""
        scan_q, late_q = quantiles if quantiles is not None else self.window_quantiles()
        return {"cycles": self.count, "overruns": self.overruns, "skipped": self.skipped,
                "scan_us": self.scan(scan_q).as_dict(),
                "lateness_us": self.lateness(late_q).as_dict(),
                "gc_runs": self.gc_runs, "gc_ms": round(self.gc_ns / 1e6, 2),
                "gc_full_ms": round(self.gc_full_last / 1e6, 2),
                "gc_full_max_ms": round(self.gc_full_max / 1e6, 2),
                "gc_full_runs": self.gc_full_runs, "gc_full_deferred": self.gc_full_deferred,
                "freezes": self.freezes, "freeze_max_ms": round(self.freeze_max / 1e6, 1)}
