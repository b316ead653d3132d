"""Operating-system help for a steady scan: sleeps to a deadline, SCHED_FIFO, locked
memory, reduced timer slack, the processor the controller runs on.

Everything here degrades gracefully: where the call is refused (no privilege, not Linux),
the caller gets False and a reason to log, never an exception.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

MCL_CURRENT = 1
MCL_FUTURE = 2


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name or "libc.so.6", use_errno=True)
    except OSError:
        return None


_LIBC = _libc()


def make_sleep_until() -> Callable[[int], None]:
    """A ``sleep_until(deadline_ns)`` on CLOCK_MONOTONIC (the clock of time.monotonic_ns).

    It is ``time.sleep`` of the time left: since Python 3.11, on Linux, that is one
    clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME) on ``now + delay`` with the GIL
    released, resumed to the same absolute deadline after a signal (PEP 475). The only
    drift is the few hundred ns between our clock read and its own, never accumulated:
    the scan loop's deadlines are absolute. It costs about 2 µs less CPU per call than the
    same clock_nanosleep called through ctypes (argument conversion, the errno dance), and
    allocates nothing that lives on. A deadline already passed returns at once, without
    a system call."""
    monotonic_ns, sleep = time.monotonic_ns, time.sleep

    def sleep_until(deadline_ns: int) -> None:
        delay = deadline_ns - monotonic_ns()
        if delay > 0:
            sleep(delay * 1e-9)
    return sleep_until


def set_fifo_priority(priority: int) -> tuple[bool, str]:
    """SCHED_FIFO at ``priority`` (1-99) for the calling thread. (done, why not)."""
    if not hasattr(os, "sched_setscheduler"):
        return False, "SCHED_FIFO is not available on this system"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return False, ("not permitted (needs CAP_SYS_NICE or an RLIMIT_RTPRIO >= "
                       f"{priority}; the systemd unit grants it)")
    except OSError as exc:
        return False, str(exc)
    return True, ""


def lock_memory() -> tuple[bool, str]:
    """mlockall(MCL_CURRENT | MCL_FUTURE): no page of the process is swapped or paged out
    in the middle of a scan. (done, why not)."""
    fn = getattr(_LIBC, "mlockall", None) if _LIBC is not None else None
    if fn is None:
        return False, "mlockall is not available on this system"
    if fn(MCL_CURRENT | MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        return False, (f"{os.strerror(err)} (needs CAP_IPC_LOCK or a large enough "
                       "RLIMIT_MEMLOCK; the systemd unit grants it)")
    return True, ""


PR_SET_TIMERSLACK = 29


def reduce_timer_slack(slack_ns: int = 1000) -> tuple[bool, str]:
    """prctl(PR_SET_TIMERSLACK) for the calling thread: the kernel may otherwise wake a
    normal (not SCHED_FIFO) thread up to 50 µs after its deadline to batch timers."""
    fn = getattr(_LIBC, "prctl", None) if _LIBC is not None else None
    if fn is None:
        return False, "prctl is not available on this system"
    if fn(PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0) != 0:
        return False, os.strerror(ctypes.get_errno())
    return True, ""


def _cpus_text(cpus: set[int]) -> str:
    return ", ".join(str(c) for c in sorted(cpus))


def _allowed() -> set[int] | None:
    """The processors this process may run on; None where affinity is not available."""
    return os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None


#: why a placement cannot be made where there is no processor affinity
NO_AFFINITY = "processor affinity is not available on this system"


def _place(cpus: set[int]) -> tuple[bool, str]:
    """Every thread of this process on ``cpus`` (the calling one first): the threads and
    processes started later inherit their starter's. (done, why not)."""
    try:
        os.sched_setaffinity(0, cpus)
        for tid in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(tid), cpus)
            except ProcessLookupError:  # the thread ended meanwhile
                pass
    except OSError as exc:
        return False, str(exc)
    return True, ""


def pin_process(cpu: int) -> tuple[bool, str]:
    """Every thread of this process on processor ``cpu`` (``plc: realtime: cpu``): the
    scan thread and the threads beside it, which share one GIL, then never wait for a
    processor that another process holds while the scan waits for the GIL. (done, why
    not): a processor this process may not use leaves it where it was."""
    allowed = _allowed()
    if allowed is None:
        return False, NO_AFFINITY
    if cpu not in allowed:
        return False, (f"processor {cpu} is not one this process may use "
                       f"({_cpus_text(allowed)})")
    return _place({cpu})


def keep_off(cpu: int) -> tuple[bool, str]:
    """This process's threads, and what it starts later, on every processor it may use but
    ``cpu`` (a side process of a plant whose controller runs there). (done, why not): with
    no other processor, it stays where it was."""
    allowed = _allowed()
    if allowed is None:
        return False, NO_AFFINITY
    if cpu not in allowed:
        return True, ""  # already off it
    if allowed == {cpu}:
        return False, f"no processor but {cpu} for this process"
    return _place(allowed - {cpu})


def leave_a_lone_processor() -> bool:
    """A process started by a controller kept to one processor (``pin_process``: it
    inherited that) moves to the machine's other processors, leaving that one to the
    controller (the reload's child, which compiles a plant for seconds). Whether it
    moved: not when it may run on more than one, nor where no other is allowed (a
    cpuset without them)."""
    allowed = _allowed()
    if allowed is None or len(allowed) != 1:
        return False
    others = set(range(os.cpu_count() or 1)) - allowed
    return bool(others) and _place(others)[0]
