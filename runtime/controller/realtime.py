"""Operating-system help for a steady scan: absolute sleeps, SCHED_FIFO, locked memory.

Everything here degrades gracefully: where the call is refused (no privilege, not Linux),
the caller gets False and a reason to log, never an exception.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import logging
import os
import time
from collections.abc import Callable

log = logging.getLogger(__name__)

CLOCK_MONOTONIC = 1
TIMER_ABSTIME = 1
MCL_CURRENT = 1
MCL_FUTURE = 2


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name or "libc.so.6", use_errno=True)
    except OSError:
        return None


_LIBC = _libc()


def make_sleep_until() -> Callable[[int], None]:
    """A ``sleep_until(deadline_ns)`` on CLOCK_MONOTONIC (the clock of time.monotonic_ns),
    absolute (TIMER_ABSTIME) when libc offers clock_nanosleep: no drift from converting to
    a relative delay, and a signal that interrupts it resumes the same absolute wait.

    Each call returns a function with its own timespec: one per scan thread, so the
    sleep allocates nothing and two threads never share it."""
    fn = getattr(_LIBC, "clock_nanosleep", None) if _LIBC is not None else None
    if fn is None or not hasattr(time, "CLOCK_MONOTONIC"):
        def relative(deadline_ns: int) -> None:
            delay = deadline_ns - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
        return relative
    fn.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.POINTER(_Timespec),
                   ctypes.POINTER(_Timespec)]
    fn.restype = ctypes.c_int
    ts = _Timespec()
    ref = ctypes.byref(ts)

    def absolute(deadline_ns: int) -> None:
        # ctypes releases the GIL during the call: other threads run while we sleep
        ts.tv_sec, ts.tv_nsec = divmod(deadline_ns, 1_000_000_000)
        while fn(CLOCK_MONOTONIC, TIMER_ABSTIME, ref, None) == errno.EINTR:
            pass
    return absolute


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
