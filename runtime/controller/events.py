"""What the charts do, logged one line per event: step changes (``log: steps``), SFCError
set and cleared, and overruns (one line per burst, with its count).

``EventWatcher`` is a listener of the daemon: after every cycle, in the idle part of the
scan thread, it takes a compact copy of each instance's watched flags (one tuple per
instance: the X flags of its steps if the plant asks for them, SFCError and SFCErrorStep)
and compares it with the previous one. Nothing is formatted there: a change is queued as
the two tuples, and a thread of its own formats and logs it, so a slow log (a full
journal pipe) never delays a scan. Every line goes through the handler's rate limit
(logsetup.RateLimit): a step line's template names its instance and step, so a chattering
step is limited on its own and the other steps are not.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from drivers.durations import format_ns
from runtime.controller.stats import ScanStats
from runtime.engine.plant import Plant
from runtime.language.flagtexts import sfcerror_cause

log = logging.getLogger(__name__)

#: an overrun burst ends after this long without an overrun, ns
OVERRUN_QUIET_NS = 1_000_000_000
#: a burst that goes on is reported at least this often, ns
OVERRUN_REPORT_NS = 10_000_000_000
#: events waiting for the log thread; more are counted as dropped
QUEUE_MAX = 10_000
#: how often the log thread looks at the queue without being woken, s
POLL_S = 0.5


class _Watched:
    """One instance: where its flags are and how they were at the last look."""

    __slots__ = ("name", "get", "prev", "steps", "max_ns", "on_msg", "off_msg")

    def __init__(self, plant: Plant, name: str, log_steps: bool) -> None:
        inst = plant.instances[name]
        prog = inst.program
        self.name = name
        self.steps = [s.name for s in inst.grafcet.leaf_steps()] if log_steps else []
        self.max_ns = {s.name: s.max_ns for s in inst.grafcet.steps.values()}
        slots = [prog.x_index(s) for s in self.steps]
        slots += [prog.var_index("SFCError"), prog.var_index("SFCErrorStep")]
        #: the watched slots' values, read straight from the instance's scan closure
        self.get: Callable[[], tuple[Any, ...]] = inst.m.getter(slots)
        self.prev = self.get()
        # one template per step: the rate limit counts each step on its own
        safe = name.replace("%", "%%")
        self.on_msg = [f"{safe}: step {s.replace('%', '%%')} activated at scan %d"
                       for s in self.steps]
        self.off_msg = [f"{safe}: step {s.replace('%', '%%')} deactivated at scan %d"
                        for s in self.steps]


class _Burst:
    """Overruns close together: reported as one line."""

    __slots__ = ("first_n", "first_t", "last_n", "last_t", "count", "longest", "skipped")

    def __init__(self, n: int, now: int) -> None:
        self.first_n = self.last_n = n
        self.first_t = self.last_t = now
        self.count = self.longest = self.skipped = 0


class EventWatcher:
    """The daemon's listener that logs chart events (see the module docstring).

    ``start()`` starts the log thread; ``close()`` reports a burst still open, logs what
    is queued and stops the thread (idempotent). The clock (monotonic ns) is injectable:
    overrun bursts are timed on it."""

    def __init__(self, plant: Plant, stats: ScanStats,
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.plant = plant
        self.stats = stats
        self.clock = clock
        self.cycle_ns = plant.cycle_ns
        self._watched = [_Watched(plant, name, idef.log_steps)
                         for name, idef in plant.pdef.instances.items()
                         if name in plant.instances]
        self._queue: collections.deque[tuple[Any, ...]] = collections.deque()
        self.dropped = 0
        self._dropped_said = 0
        self._overruns = stats.overruns
        self._skipped = stats.skipped
        self._burst: _Burst | None = None
        self._wake = threading.Event()
        self._stop = False
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()  # one drain at a time (the thread, then close)

    # -- the scan thread -----------------------------------------------------------------
    def __call__(self, n: int) -> None:
        """After cycle ``n``: queue what changed (no formatting here)."""
        changed = False
        for w in self._watched:
            cur = w.get()
            if cur != w.prev:
                self._put((n, w, w.prev, cur))
                w.prev = cur
                changed = True
        if self.stats.overruns != self._overruns or self._burst is not None:
            changed = self._look_at_overruns(n) or changed
        if changed:
            self._wake.set()

    def prepare_switch(self, plant: Plant) -> Callable[[], None]:
        """Online change: the watched flags of ``plant``, built now (any thread); the
        returned function (scan thread, at the swap) watches them from then on, their
        carried values taken as the last seen (the swap itself is no event)."""
        watched = [_Watched(plant, name, idef.log_steps)
                   for name, idef in plant.pdef.instances.items() if name in plant.instances]

        def commit() -> None:
            for w in watched:
                w.prev = w.get()
            self.plant, self._watched = plant, watched
        return commit

    def _put(self, event: tuple[Any, ...]) -> None:
        if len(self._queue) >= QUEUE_MAX:
            self.dropped += 1
        else:
            self._queue.append(event)

    def _look_at_overruns(self, n: int) -> bool:
        """Open, extend or close the burst; True if a burst was queued."""
        stats, now, b = self.stats, self.clock(), self._burst
        queued = False
        if stats.overruns != self._overruns:
            if b is not None and now - b.first_t >= OVERRUN_REPORT_NS:
                self._put(("overrun", b))
                b, queued = None, True
            if b is None:
                b = self._burst = _Burst(n, now)
            b.count += stats.overruns - self._overruns
            b.skipped += stats.skipped - self._skipped
            b.last_n, b.last_t = n, now
            b.longest = max(b.longest, stats.scan_last + stats.late_last)
            self._overruns, self._skipped = stats.overruns, stats.skipped
        elif b is not None and now - b.last_t >= OVERRUN_QUIET_NS:
            self._put(("overrun", b))
            self._burst, queued = None, True
        return queued

    # -- the log thread --------------------------------------------------------------------
    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="softplc-events",
                                        daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Report an open burst, log what is queued, stop the thread. Idempotent; call it
        once the scan thread has stopped."""
        if self._burst is not None:
            self._put(("overrun", self._burst))
            self._burst = None
        self._stop = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._drain()

    def _run(self) -> None:
        while not self._stop:
            self._wake.wait(POLL_S)
            self._wake.clear()
            try:
                self._drain()
            except Exception:  # noqa: BLE001 - the thread must not die: say why, go on
                log.exception("event log failed")

    def _drain(self) -> None:
        with self._lock:
            q = self._queue
            while q:
                event = q.popleft()
                if event[0] == "overrun":
                    self._say_overruns(event[1])
                else:
                    self._say_changes(*event)
            if self.dropped != self._dropped_said:
                log.warning("%d chart events not logged (the log was too slow)",
                            self.dropped - self._dropped_said)
                self._dropped_said = self.dropped

    def _say_changes(self, n: int, w: _Watched, prev: tuple[Any, ...],
                     cur: tuple[Any, ...]) -> None:
        k = len(w.steps)
        was_error, was_step = prev[k], prev[k + 1]
        if was_error and not cur[k]:
            log.info("%s: SFCError cleared (was %s), at scan %d", w.name,
                     sfcerror_cause(was_step), n)
        # deactivations first: a transition leaves its source steps, then enters
        for j in range(k):
            if prev[j] and not cur[j]:
                log.info(w.off_msg[j], n)
        for j in range(k):
            if cur[j] and not prev[j]:
                log.info(w.on_msg[j], n)
        if cur[k] and not was_error:
            step = cur[k + 1]
            limit = w.max_ns.get(step)
            if limit:
                log.warning("%s: SFCError: step %s active longer than its max %s, at scan "
                            "%d", w.name, step, format_ns(limit), n)
            else:  # written (the console's set, the chart itself), no step's supervision
                log.warning("%s: SFCError %s, at scan %d", w.name, sfcerror_cause(step), n)

    def _say_overruns(self, b: _Burst) -> None:
        cycle = f"{self.cycle_ns / 1e6:g} ms"
        longest = f"{b.longest / 1e6:.1f} ms"
        if b.first_n == b.last_n:
            log.warning("%d cycle%s overran the %s cycle at scan %d (the longest took %s; "
                        "%d deadlines skipped)", b.count, "" if b.count == 1 else "s",
                        cycle, b.first_n, longest, b.skipped)
        else:
            log.warning("%d cycles overran the %s cycle between scans %d and %d (in "
                        "%.3f s; the longest took %s; %d deadlines skipped)", b.count,
                        cycle, b.first_n, b.last_n, (b.last_t - b.first_t) / 1e9,
                        longest, b.skipped)
