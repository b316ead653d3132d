"""The scan loop's sleep (``make_sleep_until``, time.sleep of the time left): never wakes
before its deadline on CLOCK_MONOTONIC, not even when a signal interrupts it, and a
deadline already passed returns at once."""

from __future__ import annotations

import signal
import threading
import time
from types import FrameType

from runtime.controller.realtime import make_sleep_until

MS = 1_000_000


def test_never_wakes_before_the_deadline_across_many_short_sleeps() -> None:
    sleep_until = make_sleep_until()
    deadline = time.monotonic_ns()
    early = []
    for i in range(200):  # odd delays: sub-µs remainders must round up, never down
        deadline += 100_000 + 7 * i + 1
        sleep_until(deadline)
        if (now := time.monotonic_ns()) < deadline:
            early.append(deadline - now)
    assert not early, early


def test_a_signal_in_the_middle_resumes_the_same_deadline() -> None:
    assert threading.current_thread() is threading.main_thread()
    got: list[int] = []

    def handler(signum: int, frame: FrameType | None) -> None:
        got.append(time.monotonic_ns())
    old = signal.signal(signal.SIGALRM, handler)
    try:
        sleep_until = make_sleep_until()
        # 50 ms into a 1 s sleep: a pause of this process before the sleep (the machine's)
        # still leaves the signal inside it
        deadline = time.monotonic_ns() + 1000 * MS
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        sleep_until(deadline)
        woke = time.monotonic_ns()
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert got and got[0] < deadline, "the signal did not come during the sleep"
    assert woke >= deadline


def test_a_deadline_already_passed_returns_at_once() -> None:
    sleep_until = make_sleep_until()
    start = time.monotonic_ns()
    batches = []  # the least of five: the host's stolen time is counted as this thread's
    for _ in range(5):
        t0 = time.thread_time_ns()
        for _ in range(1000):
            sleep_until(start - 1)
        batches.append(time.thread_time_ns() - t0)
    # without a system call: far below one real sleep per call (~15 µs of CPU each here)
    assert min(batches) / 1000 < 5_000, batches
