"""What made each wake-up of a daemon's scan thread late: the CPU scheduler, or the
process itself (tests and benches only).

``SchedProbe.wrap`` wraps the scan thread's ``sleep_until`` and reads the thread's
scheduler statistics around each sleep (/proc/thread-self/schedstat: the ns it ran on a
CPU, and the ns it spent runnable but waiting for one). A wake-up's lateness minus both
is the time the thread was woken yet *blocked*: in a Python process, waiting for the GIL
held by another of its threads (a console thread serving a flood, say). That part is the
process's own doing, whatever else runs on the machine; the run-queue part is the
machine's (other processes, the clients' own CPU), which only real-time priority takes
out. So a test can hold the console to "it never blocks the scan" on a loaded shared
machine, where lateness and overruns alone say as much about the other jobs.

Each wake-up costs two reads of a /proc file (a few µs): fine for a test, not for the
scan of a controller.

The host of a virtual machine adds to "blocked" what it takes from the VM (steal time, a
timer delivered late): a thread alone in its process sees that much too. So a test
compares with such a thread, in a process of its own, paced the same way at the same
time (``python -m tests.console.schedprobe SECONDS [CYCLE_MS [FIFO_PRIORITY]]``: one
JSON line of Wakes).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from array import array
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from runtime.controller.realtime import make_sleep_until, reduce_timer_slack, set_fifo_priority

SCHEDSTAT = "/proc/thread-self/schedstat"
#: a wake-up later than this is counted as ``Wakes.late``, µs (a quarter of a 10 ms cycle)
LATE_US = 2500.0


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
    #: wake-ups later than LATE_US
    late: int
    #: wake-ups a whole cycle late or more (a scan paced so would have overrun), and the
    #: deadlines they passed over (it would have skipped), when the cycle is known
    #: (``control``)
    missed: int = 0
    skipped: int = 0


class SchedProbe:
    """Per wake-up lateness, and time on a CPU or waiting for one (``runq``: the time it
    was not blocked), of the thread sleeping through ``wrap``'s function, recorded between
    ``start()`` and ``stop()`` (ns, preallocated)."""

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
        has_stats = available()

        def not_blocked() -> int:
            """ns on a CPU or waiting for one, since the thread started (0 where the kernel
            keeps no such statistics: every wake-up then counts as blocked)."""
            if not has_stats:
                return 0
            if not files:  # opened in the thread that sleeps: thread-self is that one
                files.append(os.open(SCHEDSTAT, os.O_RDONLY))
            ran, waited = os.pread(files[0], 128, 0).split()[:2]
            return int(ran) + int(waited)

        def probed(deadline: int) -> None:
            if not self.on or deadline <= mono():
                sleep_until(deadline)
                return
            before = not_blocked()
            sleep_until(deadline)
            wake = mono()
            waited = not_blocked() - before
            i = self.n
            if i < self.capacity:
                self._late[i] = wake - deadline
                self._runq[i] = waited
                self.n = i + 1
        return probed

    def start(self) -> None:
        self.n = 0
        self.on = True

    def stop(self, cycle_ns: int = 0) -> Wakes:
        self.on = False
        return self.wakes(cycle_ns)

    def wakes(self, cycle_ns: int = 0) -> Wakes:
        """The wake-ups recorded; ``cycle_ns``: the pacing, to count those a cycle late."""
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
                     sum(1 for b in blocked if b > 1_000_000), sum(blocked) / 1e6,
                     sum(1 for x in late if x > LATE_US * 1e3),
                     sum(1 for x in late if x >= cycle_ns) if cycle_ns else 0,
                     sum(x // cycle_ns for x in late if x >= cycle_ns) if cycle_ns else 0)


#: the neighbour of a control's paced thread: bursts of Python this long (holding the GIL),
#: then a sleep as long (releasing it), s
NEIGHBOUR_BURST_S = 0.0005
#: the neighbours a control may have: "bursts" (a console thread keeping its work short),
#: "busy" (a feed thread serving a flood: Python all the time, the GIL given up only at
#: the interpreter's switch interval)
NEIGHBOURS = ("bursts", "busy")


def _neighbour(stop: list[int], kind: str) -> None:
    """Pure-Python work at normal priority (``NEIGHBOURS``): a thread of a controller's
    process, which the machine may take the processor from while it holds the GIL."""
    while not stop:
        end = time.perf_counter() + NEIGHBOUR_BURST_S
        while time.perf_counter() < end:
            pass
        if kind == "bursts":
            time.sleep(NEIGHBOUR_BURST_S)


def control(seconds: float, cycle_ms: float = 10.0, priority: int = 0,
            ready: Callable[[], None] | None = None, neighbour: str = "") -> Wakes:
    """Wake-ups of a thread alone in its process (this one's main thread), paced to
    absolute deadlines every ``cycle_ms`` for ``seconds`` (or until SIGTERM), with the scan
    thread's timer slack (and SCHED_FIFO ``priority`` if not 0, where permitted): what the
    machine alone does to a scan thread's wake-ups. With a ``neighbour`` (``NEIGHBOURS``), a
    second thread of the process works meanwhile (``_neighbour``): what the machine does
    to a scan thread whose process has a busy thread (held behind the GIL while the
    machine keeps that thread from the processor). ``ready()`` is called as it starts."""
    stop: list[int] = []
    if neighbour:  # started first: it keeps normal priority
        threading.Thread(target=_neighbour, args=(stop, neighbour), daemon=True).start()
    reduce_timer_slack()
    if priority:
        set_fifo_priority(priority)
    probe = SchedProbe()
    sleep_until = probe.wrap(make_sleep_until())
    cycle = int(cycle_ms * 1e6)
    stopped: list[int] = []
    signal.signal(signal.SIGTERM, lambda *_: stopped.append(1))
    deadline = time.monotonic_ns() + cycle
    end = deadline + int(seconds * 1e9)
    probe.start()
    if ready is not None:
        ready()
    while deadline < end and not stopped:
        sleep_until(deadline)
        deadline += cycle
    stop.append(1)
    return probe.stop(cycle)


def beyond_the_machine(missed: Mapping[str, int], lone: Wakes, watchdog_ms: float
                       ) -> list[str]:
    """What a controller missed (``missed``: its overruns, skipped deadlines and freezes
    over a window) beyond what the machine did to ``lone``, a control paced like its scan
    over the same window (``lone_thread`` with a "busy" neighbour: the controller's process
    has its feed and console threads): overruns more than twice the control's wake-ups a
    cycle late, skipped deadlines more than twice those it passed over, each plus 1; a
    freeze where the control was never held for a watchdog. Empty when the controller
    missed nothing of its own doing; on a quiet machine the control misses nothing, and
    neither may the controller (but one)."""
    out = []
    if missed["overruns"] > 2 * lone.missed + 1:
        out.append(f"{missed['overruns']} overruns against {lone.missed} wake-ups a cycle "
                   "late of the control")
    if missed["skipped"] > 2 * lone.skipped + 1:
        out.append(f"{missed['skipped']} skipped deadlines against {lone.skipped} of the "
                   "control")
    if missed["freezes"] and lone.late_max < watchdog_ms * 1e3:
        out.append(f"{missed['freezes']} freezes, the lone thread at most "
                   f"{lone.late_max / 1e3:.0f} ms late")
    return out


@contextmanager
def lone_thread(cycle_ms: float, priority: int, neighbour: str = "",
                most_s: float = 900.0) -> Iterator[list[Wakes]]:
    """A lone thread paced like a scan (``control``, with its busy ``neighbour`` if asked),
    in a process of its own, running through the ``with`` block (at most ``most_s``): the
    list holds its Wakes after it. The block starts once the thread runs."""
    lone = subprocess.Popen([sys.executable, "-m", "tests.console.schedprobe", str(most_s),
                             str(cycle_ms), str(priority), neighbour or "-"],
                            stdout=subprocess.PIPE, text=True,
                            cwd=Path(__file__).resolve().parents[2])
    assert lone.stdout is not None
    got: list[Wakes] = []
    try:
        assert lone.stdout.readline() == "ready\n", "the lone thread did not start"
        yield got
    finally:
        lone.send_signal(signal.SIGTERM)
        out, _ = lone.communicate(timeout=120)
    got.append(Wakes(**json.loads(out)))


if __name__ == "__main__":
    argv = sys.argv[1:]

    def say_ready() -> None:
        sys.stdout.write("ready\n")
        sys.stdout.flush()
    wakes = control(float(argv[0]), float(argv[1]) if len(argv) > 1 else 10.0,
                    int(argv[2]) if len(argv) > 2 else 0, say_ready,
                    neighbour=argv[3] if argv[3:4] and argv[3] in NEIGHBOURS else "")
    sys.stdout.write(json.dumps(asdict(wakes)) + "\n")
