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

import ctypes
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
from typing import TYPE_CHECKING, Any

from runtime.controller.realtime import make_sleep_until, reduce_timer_slack, set_fifo_priority

if TYPE_CHECKING:
    from runtime.controller.scheduler import Scheduler

SCHEDSTAT = "/proc/thread-self/schedstat"
#: a wake-up later than this is counted as ``Wakes.late``, µs (a quarter of a 10 ms cycle)
LATE_US = 2500.0


#: libc called with the GIL held (``PyDLL``): a probe's read of its statistics never
#: lets another thread of the process take the GIL (``os.pread`` releases it, and the
#: thread then waits to get it back: a wait of the probe's own making in the figures)
_HELD = ctypes.PyDLL(None, use_errno=True)
_HELD.pread.argtypes = (ctypes.c_int, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_long)
_HELD.pread.restype = ctypes.c_ssize_t


def thread_schedstat(files: list[Any]) -> tuple[int, int, int]:
    """The calling thread's (ns on a processor, ns runnable waiting for one, times put on
    one) since it started; ``files`` keeps the file and a buffer, opened at the first call
    (from the thread measured: /proc/thread-self is the caller). The GIL is held
    throughout. The time on a processor is the thread's CPU clock: up to date, where
    schedstat's own figure for a running thread is the one of its last tick or scheduler
    event (up to a tick stale: 4 ms at HZ=250, four cycles at 1 ms)."""
    if not files:
        files += [os.open(SCHEDSTAT, os.O_RDONLY), ctypes.create_string_buffer(128)]
    fd, buf = files
    n = _HELD.pread(fd, buf, 128, 0)
    if n <= 0:
        raise OSError(ctypes.get_errno(), f"{SCHEDSTAT}: read failed")
    _, waited, slices = buf.raw[:n].split()[:3]
    return time.thread_time_ns(), int(waited), int(slices)


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
    #: of ``missed``, those whose thread was put on a processor more than once from its
    #: sleep to its return (0 for a lone thread, which nothing of its process can hold: a
    #: check of OverrunProbe's rule that one slice means the machine's)
    rescheduled: int = 0


class SchedProbe:
    """Per wake-up lateness, and time on a CPU or waiting for one (``runq``: the time it
    was not blocked), of the thread sleeping through ``wrap``'s function, recorded between
    ``start()`` and ``stop()`` (ns, preallocated)."""

    def __init__(self, capacity: int = 1 << 17) -> None:
        self._late = array("q", bytes(8 * capacity))
        self._runq = array("q", bytes(8 * capacity))
        self._slices = array("q", bytes(8 * capacity))
        self.capacity = capacity
        self.n = 0
        self.on = False

    def wrap(self, sleep_until: Callable[[int], None]) -> Callable[[int], None]:
        """``sleep_until`` recording each wake-up (call it from the sleeping thread)."""
        mono = time.monotonic_ns
        files: list[Any] = []
        has_stats = available()

        def not_blocked() -> tuple[int, int]:
            """ns on a CPU or waiting for one, and the times the thread was put on a
            processor, since it started (0, 0 where the kernel keeps no such statistics:
            every wake-up then counts as blocked)."""
            if not has_stats:
                return 0, 0
            ran, waited, slices = thread_schedstat(files)
            return ran + waited, slices

        def probed(deadline: int) -> None:
            if not self.on or deadline <= mono():
                sleep_until(deadline)
                return
            before, slices = not_blocked()
            sleep_until(deadline)
            wake = mono()
            after, slices2 = not_blocked()
            i = self.n
            if i < self.capacity:
                self._late[i] = wake - deadline
                self._runq[i] = after - before
                self._slices[i] = slices2 - slices
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
                     sum(x // cycle_ns for x in late if x >= cycle_ns) if cycle_ns else 0,
                     sum(1 for x, k in zip(self._late[:n], self._slices[:n], strict=True)
                         if x >= cycle_ns and k > 1) if cycle_ns else 0)


@dataclass(frozen=True)
class Overrun:
    """One overrun of a scheduler's scan (its end at or after the next deadline), ns.

    ``slept``: the scan thread went to sleep before the deadline (False: its idle work
    ran past it); ``sleep_slices``, ``scan_slices``: the times the kernel put the thread
    on a processor from the start of its sleep to its wake-up's return to Python, and
    during the scan (1 and 0 when it kept its processor from its first instant on one
    after the timer; more when it waited again: for the GIL, another of the process's
    threads holding it, or preempted by a task of higher priority); ``ran``: its
    processor time over both; ``runq``: the time it was runnable waiting for a
    processor; ``others_ran``: the processor time of the process's other threads from
    the start of the sleep to the wake-up (all of them: whoever held the GIL ran at most
    that long; each thread's own clock: ``OtherThreads``); ``idle``, ``idle_ran``, ``idle_slices``:
    from the end of the scan before to the start of this sleep (its idle work), the
    time, the thread's processor time and the times it was put on a processor (0 for
    the first scan probed: unknown).
    Processor times exclude what the host of a virtual machine took (steal), where the
    kernel accounts it (CONFIG_PARAVIRT_TIME_ACCOUNTING)."""

    deadline: int
    late: int
    scan: int
    slept: bool
    sleep_slices: int
    scan_slices: int
    ran: int
    runq: int
    others_ran: int
    idle: int
    idle_ran: int
    idle_slices: int

    def machines(self, cycle_ns: int) -> bool:
        """Whether the machine made it. The thread kept its processor through the scan
        and used less than a cycle of processor time, and either:

        - it slept before its deadline and kept its processor from its first instant on
          one after the timer (the time lost was a timer delivered late, a processor
          given late, the host running something else);
        - or it waited for the GIL while its holder could not have run for even half of
          that wait (the process's other threads ran less than half of ``late`` in all:
          the holder was kept from its processor, the lock-holder preemption of a
          virtual machine's host).

        Everything else is counted the process's: a preemption by a kernel thread of
        higher priority too, and idle work that ended after the deadline even when the
        machine paused the whole process meanwhile (the daemon reports such a pause as a
        freeze when it passes the watchdog)."""
        if not self.slept or self.scan_slices > 0 or self.ran >= cycle_ns:
            return False
        return self.sleep_slices <= 1 or 2 * self.others_ran < self.late


class OverrunProbe:
    """Records each overrun of a Scheduler's scans (``install`` before it runs) between
    ``start()`` and ``stop()``: whether the machine or the process made it (``Overrun``).
    Three reads of /proc/thread-self/schedstat a cycle (a few µs each) and two of each
    other thread's processor time (``OtherThreads``: about 1 µs a thread), in the scan
    thread; meaningful with the scan at SCHED_FIFO (at normal priority any process may
    preempt it, and that counts as the process's)."""

    def __init__(self, cycle_ns: int, capacity: int = 4096) -> None:
        self.cycle_ns = cycle_ns
        self.capacity = capacity
        self.on = False
        self.seen: list[Overrun] = []
        self._others = OtherThreads()

    def install(self, sched: Scheduler) -> None:
        """Wrap ``sched``'s sleep and body (its run loop binds them as it starts)."""
        sleep_until, body, mono = sched.sleep_until, sched.body, time.monotonic_ns
        cycle = self.cycle_ns
        files: list[Any] = []
        # at the sleep's start, at the wake-up: (monotonic ns, ran, waited, slices)
        marks: list[tuple[int, int, int, int]] = [(0, 0, 0, 0), (0, 0, 0, 0)]
        due = [0]
        # at the end of the scan before: (monotonic ns, ran, slices); (0, 0, 0) unknown
        ended = [(0, 0, 0)]
        others = self._others

        def stat() -> tuple[int, int, int, int]:
            ran, waited, slices = thread_schedstat(files)  # the scan thread's
            return mono(), ran, waited, slices

        def probed_sleep(deadline: int) -> None:
            if not self.on:
                due[0] = 0
                sleep_until(deadline)
                return
            due[0] = deadline
            if not others.listed:  # the first probed sleep since start()
                others.list(mono())
            marks[0] = stat()
            others.read(0)
            sleep_until(deadline)
            others.read(1)
            marks[1] = stat()

        def probed_body(wake: int) -> Any:
            if not self.on or not due[0]:
                ended[0] = (0, 0, 0)
                return body(wake)
            try:
                return body(wake)
            finally:
                end, ran, waited, slices = stat()
                deadline = due[0]
                if end >= deadline + cycle and len(self.seen) < self.capacity:
                    (t0, ran0, waited0, slices0), (_, ran1, _, slices1) = marks
                    e_at, e_ran, e_slices = ended[0]
                    self.seen.append(Overrun(deadline, wake - deadline, end - wake,
                                             t0 < deadline, slices1 - slices0,
                                             slices - slices1, ran - ran0,
                                             waited - waited0, others.ran(),
                                             t0 - e_at if e_at else 0,
                                             ran0 - e_ran if e_at else 0,
                                             slices0 - e_slices if e_at else 0))
                ended[0] = (end, ran, slices)
                if end >= others.listed + THREADS_EVERY_NS:
                    others.list(end)
        sched.sleep_until = probed_sleep
        sched.body = probed_body

    def start(self) -> None:
        self.seen = []
        self._others.listed = 0  # listed again by the scan thread, at its next sleep
        self.on = True

    def stop(self) -> list[Overrun]:
        self.on = False
        return self.seen


#: while an OverrunProbe records, the process's threads are listed again this often, ns
#: (a thread started in between is not counted in ``others_ran`` until then)
THREADS_EVERY_NS = 1_000_000_000


def thread_clock(tid: int) -> int:
    """The clock of thread ``tid``'s processor time (its kernel id), for
    ``time.clock_gettime_ns``: Linux's encoding, as glibc's ``pthread_getcpuclockid``
    (``CPUCLOCK_PERTHREAD_MASK | CPUCLOCK_SCHED``). The kernel brings a thread's figure up
    to date at each read of its clock, even while it runs on another processor."""
    return (~tid << 3) | 6


class OtherThreads:
    """The processor time of the process's threads but the calling one, at two marks.

    Each thread's own clock (``thread_clock``), read one by one: the process's clock
    (``time.process_time_ns``) brings only the calling thread's figure up to date, and
    leaves another thread's up to a tick stale while it runs on another processor (off by
    up to ±1.5 ms for a thread running all along, measured here over 0.7 ms sleeps).
    About 1 µs a thread a mark, with the GIL held."""

    def __init__(self) -> None:
        #: the threads' kernel ids and their clocks
        self.tids: list[int] = []
        self.clocks: list[int] = []
        self.marks = (array("q"), array("q"))
        #: when the threads were last listed, monotonic ns
        self.listed = 0

    def list(self, now: int) -> None:
        """List the process's threads but the caller's (the thread that reads the
        marks), from /proc; ``now``: monotonic ns."""
        me = threading.get_native_id()
        self.tids = tids = sorted(int(t) for t in os.listdir("/proc/self/task")
                                  if int(t) != me)
        self.clocks = [thread_clock(t) for t in tids]
        self.marks = (array("q", [-1] * len(tids)), array("q", [-1] * len(tids)))
        self.listed = now

    def read(self, mark: int) -> None:
        """Each listed thread's processor time into ``marks[mark]`` (-1: it has ended)."""
        values, read = self.marks[mark], time.clock_gettime_ns
        i = 0
        for c in self.clocks:
            try:
                values[i] = read(c)
            except OSError:
                values[i] = -1
            i += 1

    def ran(self) -> int:
        """The processor time of the threads read at both marks, from the first to the
        second, ns (a thread that ended between them is left out: what it ran then is
        unknown)."""
        return sum(self.each().values())

    def each(self) -> dict[int, int]:
        """Each thread read at both marks: its processor time from the first to the
        second, ns, by kernel id."""
        a, b = self.marks
        return {t: y - x for t, x, y in zip(self.tids, a, b, strict=True)
                if x >= 0 and y >= 0}


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


#: deadlines the controller may skip beyond twice its control's: the control runs on
#: the other processor, so a pause of the host on the controller's processor alone (tens
#: of ms at busy times on this VM: one overrun, 2-4 deadlines at a 10 ms cycle) is not
#: seen by it. Its own doing shows above that: a block of 100 ms is 10 at 10 ms
SKIPPED_SLACK = 5


def beyond_the_machine(missed: Mapping[str, int], lone: Wakes, watchdog_ms: float
                       ) -> list[str]:
    """What a controller missed (``missed``: its overruns, skipped deadlines and freezes
    over a window) beyond what the machine did to ``lone``, a control paced like its scan
    over the same window (``lone_thread`` with a "busy" neighbour: the controller's process
    has its feed and console threads): overruns more than twice the control's wake-ups a
    cycle late plus 1, skipped deadlines more than twice those it passed over plus
    SKIPPED_SLACK; a freeze where the control was never held for a watchdog. Empty when
    the controller missed nothing of its own doing; on a quiet machine the control misses
    nothing, and neither may the controller (but one overrun, one short stall)."""
    out = []
    if missed["overruns"] > 2 * lone.missed + 1:
        out.append(f"{missed['overruns']} overruns against {lone.missed} wake-ups a cycle "
                   "late of the control")
    if missed["skipped"] > 2 * lone.skipped + SKIPPED_SLACK:
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
