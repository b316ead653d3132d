"""What made each wake-up of a daemon's scan thread late: the CPU scheduler, or the
process itself (tests and benches only).

``SchedProbe.wrap`` wraps the scan thread's ``sleep_until`` and reads the thread's
run-queue delay around each sleep (/proc/thread-self/schedstat, second field: the ns the
thread spent runnable but waiting for a CPU). A wake-up's lateness minus that delay is the
time the thread was woken yet *blocked*: in a Python process, waiting for the GIL held by
another of its threads (a console thread serving a flood, say). That part is the
process's own doing, whatever else runs on the machine; the run-queue part is the
machine's (other processes, the clients' own CPU), which only real-time priority takes
out. So a test can hold the console to "it never blocks the scan" on a loaded shared
machine, where lateness and overruns alone say as much about the other jobs.

Each wake-up costs two reads of a /proc file (a few µs): fine for a test, not for the
scan of a controller.
"""

from __future__ import annotations

import os
import time
from array import array
from collections.abc import Callable
from dataclasses import dataclass

SCHEDSTAT = "/proc/thread-self/schedstat"


def available() -> bool:
    """Whether the kernel keeps per-thread scheduler statistics (CONFIG_SCHED_INFO)."""
    return os.path.exists(SCHEDSTAT)


@dataclass(frozen=True)
class Wakes:
    """The wake-ups recorded in one window, µs: lateness, run-queue delay, blocked."""

    count: int
    late_p50: float
    late_p99: float
    late_max: float
    runq_p99: float
    runq_max: float
    blocked_p50: float
    blocked_p99: float
    blocked_max: float
    #: wake-ups blocked longer than 1 ms, and the time they were blocked in all (ms)
    blocked_over_1ms: int
    blocked_ms: float


class SchedProbe:
    """Per wake-up lateness and run-queue delay of the thread sleeping through ``wrap``'s
    function, recorded between ``start()`` and ``stop()`` (ns, preallocated)."""

    def __init__(self, capacity: int = 1 << 17) -> None:
        self._late = array("q", bytes(8 * capacity))
        self._runq = array("q", bytes(8 * capacity))
        self.capacity = capacity
        self.n = 0
        self.on = False

    def wrap(self, sleep_until: Callable[[int], None]) -> Callable[[int], None]:
        """``sleep_until`` recording each wake-up (call it from the sleeping thread)."""
        mono = time.monotonic_ns
        files: list[int] = []

        def run_delay() -> int:
            if not files:  # opened in the thread that sleeps: thread-self is that one
                files.append(os.open(SCHEDSTAT, os.O_RDONLY))
            return int(os.pread(files[0], 128, 0).split()[1])

        def probed(deadline: int) -> None:
            if not self.on or deadline <= mono():
                sleep_until(deadline)
                return
            before = run_delay()
            sleep_until(deadline)
            wake = mono()
            waited = run_delay() - before
            i = self.n
            if i < self.capacity:
                self._late[i] = wake - deadline
                self._runq[i] = waited
                self.n = i + 1
        return probed

    def start(self) -> None:
        self.n = 0
        self.on = True

    def stop(self) -> Wakes:
        self.on = False
        return self.wakes()

    def wakes(self) -> Wakes:
        n = min(self.n, self.capacity)
        late = sorted(self._late[:n])
        runq = sorted(self._runq[:n])
        blocked = sorted(max(0, a - b) for a, b in zip(self._late[:n], self._runq[:n],
                                                      strict=True))

        def q(values: list[int], p: float) -> float:
            return values[min(len(values) - 1, int(p * (len(values) - 1)))] / 1e3 \
                if values else 0.0
        return Wakes(n, q(late, 0.5), q(late, 0.99), q(late, 1.0), q(runq, 0.99), q(runq, 1.0),
                     q(blocked, 0.5), q(blocked, 0.99), q(blocked, 1.0),
                     sum(1 for b in blocked if b > 1_000_000), sum(blocked) / 1e6)
