"""``bench.observers --rounds``: which piece of the feed thread's and the console
thread's work was running when a scan was due, in processor time. Not a test.

Wrappers installed on the instances (``Rounds.install``) time each call of the pieces
named in STAGES, in the observed window only: its start and end (monotonic ns), the
calling thread's processor time over it (``time.thread_time_ns``: its own work, not
the time it waited for the GIL or was off a processor), the time it waited runnable for
a processor over it (the kernel's ``run_delay`` of the thread, /proc/thread-self/schedstat:
what the rest of the machine took from it; the rest of its time off a processor it
slept: waiting for the GIL, a pause, I/O) and the deadline of the scan after its window
(``ScanWindow.closes`` + ``quiet_s``: the next scan's). Nested pieces
(the feed's ``_flush`` calls ``_send``) are timed each. The report:

- per piece: its calls, processor time (p50, p99, max), wall time p99, the calls that
  began after their window had closed (in the quiet time before a deadline), and the
  calls that began before a deadline and ended after it ("across"); of those, their
  processor time (p50, max) and how many used less than half their wall time (off a
  processor, or waiting for the GIL, for most of it: a piece that pauses until the
  next window, as the percentiles do, is across without harm), and of those how many
  spent most of the time off a processor waiting for one (runq) rather than asleep;
- per overrun the process made (``schedprobe.Overrun``): the pieces that were running
  while the scan waited (from its deadline to its wake-up), with when they began
  relative to the deadline, their wall, processor and runnable-waiting time.

Each wrapped call costs two clock reads of each kind, two reads of the thread's
schedstat (an open file read again from its start, about 1 µs each) and six stores
(about 3 µs); a run for the attribution, not for the figures of the table."""

from __future__ import annotations

import os
import threading
import time
from array import array
from collections.abc import Callable
from typing import Any

from bench.opcua import out
from runtime.controller.stats import percentiles
from tests.console.schedprobe import Overrun

#: the pieces timed, per owner: the feed thread's round (FeedServer._round) and the
#: console socket thread's window (ConsoleServer._serve_window)
STAGES = {"feed": ("_write_image", "_publish", "_status_of", "_alarm_changes", "_queue_why",
                  "_flush", "_send", "_serve", "_read"),
          "console": ("_io", "_work", "_tick", "_flush")}
#: one record: piece, start, end, processor ns, the deadline after its window, ns
#: waiting runnable for a processor
FIELDS = 6


def _run_delay_reader() -> Callable[[], int]:
    """A reader of the calling thread's time waiting runnable for a processor, ns (the
    second figure of /proc/thread-self/schedstat), from a file kept open per thread."""
    fds: dict[int, int] = {}

    def run_delay() -> int:
        tid = threading.get_native_id()
        fd = fds.get(tid)
        if fd is None:
            fd = fds[tid] = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
        return int(os.pread(fd, 64, 0).split()[1])
    return run_delay


def _q(values: list[int], q: float) -> int:
    return percentiles(array("q", values), len(values), (q,))[0]


class Rounds:
    """The records of the observed window (``on``), at most ``capacity`` calls."""

    def __init__(self, capacity: int = 400_000) -> None:
        self.on = False
        self.capacity = capacity
        self.names: list[str] = []
        #: per piece, its window's quiet time before a deadline, ns
        self.quiet: list[int] = []
        self.rec = array("q", bytes(8 * FIELDS * capacity))
        self.n = 0
        self._run_delay = _run_delay_reader()

    def install(self, obj: Any, owner: str, window: Any) -> None:
        """Wrap ``obj``'s pieces of STAGES[owner]; ``window``: its ScanWindow."""
        for name in STAGES[owner]:
            fn = getattr(obj, name, None)
            if fn is None:
                continue
            self.names.append(f"{owner}.{name.lstrip('_')}")
            self.quiet.append(int(window.quiet_s * 1e9))
            setattr(obj, name, self._timed(fn, len(self.names) - 1, window))

    def _timed(self, fn: Callable[..., Any], k: int, window: Any) -> Callable[..., Any]:
        rec, mono, cpu, cap = self.rec, time.monotonic_ns, time.thread_time_ns, self.capacity
        runq = self._run_delay

        def timed(*args: Any, **kw: Any) -> Any:
            if not self.on:
                return fn(*args, **kw)
            due = int((window.closes + window.quiet_s) * 1e9)
            q0 = runq()
            t0, c0 = mono(), cpu()
            try:
                return fn(*args, **kw)
            finally:
                c1, t1 = cpu(), mono()
                q1 = runq()
                i = self.n
                if i < cap:
                    self.n = i + 1
                    j = FIELDS * i
                    rec[j], rec[j + 1], rec[j + 2] = k, t0, t1
                    rec[j + 3], rec[j + 4], rec[j + 5] = c1 - c0, due, q1 - q0
        return timed

    def _records(self) -> list[tuple[int, int, int, int, int, int]]:
        r = self.rec
        return [(r[j], r[j + 1], r[j + 2], r[j + 3], r[j + 4], r[j + 5])
                for j in range(0, FIELDS * self.n, FIELDS)]

    def report(self, overruns: list[Overrun], process: Callable[[Overrun], bool],
               top: int = 12) -> None:
        recs = self._records()
        out(f"\n--rounds: {len(recs)} calls timed in the observed window"
            + (" (capacity reached: the last ones not)" if self.n >= self.capacity else "")
            + "; us (closed: began after its window had closed, in the quiet time "
              "before a deadline; across: began before the next scan's deadline, ended "
              "after it; off: of those, processor time under half the wall time; runq: of those, "
              "waiting runnable for a processor more than asleep)")
        out("| piece | calls | cpu p50 | cpu p99 | cpu max | wall p99 | closed | across | "
            "across cpu p50 | across cpu max | off | runq |")
        out("|---|---|---|---|---|---|---|---|---|---|---|---|")
        for k, name in enumerate(self.names):
            mine = [r for r in recs if r[0] == k]
            if not mine:
                continue
            cpus = [r[3] for r in mine]
            walls = [r[2] - r[1] for r in mine]
            across = [r for r in mine if r[1] < r[4] <= r[2]]
            acpu = [r[3] for r in across]
            offs = [r for r in across if 2 * r[3] < r[2] - r[1]]
            off = len(offs)
            # off a processor: waiting for one (r[5]) or asleep (the rest)
            queued = sum(1 for r in offs if 2 * r[5] > r[2] - r[1] - r[3])
            closed = sum(1 for r in mine if r[4] - self.quiet[k] <= r[1] < r[4])
            out(f"| {name} | {len(mine)} | {_q(cpus, .5) / 1e3:.0f} | "
                f"{_q(cpus, .99) / 1e3:.0f} | {max(cpus) / 1e3:.0f} | "
                f"{_q(walls, .99) / 1e3:.0f} | {closed} | {len(across)} | "
                f"{_q(acpu, .5) / 1e3:.0f} | {max(acpu, default=0) / 1e3:.0f} | {off} | "
                f"{queued} |")
        ours = [o for o in overruns if process(o)]
        out(f"\nthe process's overruns of the observed window ({len(ours)}): the pieces "
            "running while the scan waited (began us before its deadline, wall us, "
            "processor us, us waiting runnable for a processor); none: no timed piece ran then")
        for o in ours[:top]:
            end = o.deadline + o.late
            during = [r for r in recs if r[1] < end and r[2] > o.deadline]
            said = "; ".join(f"{self.names[r[0]]} {(o.deadline - r[1]) / 1e3:.0f} before, "
                             f"{(r[2] - r[1]) / 1e3:.0f} wall, {r[3] / 1e3:.0f} cpu, "
                             f"{r[5] / 1e3:.0f} runq"
                             for r in during) or "none"
            out(f"- late {o.late / 1e3:.0f} us: {said}")
