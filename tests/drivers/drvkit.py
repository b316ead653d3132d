"""Helpers shared by the driver tests and bench/io.py: a fake clock, waiting for threads."""

from __future__ import annotations

import time
from collections.abc import Callable


class FakeClock:
    """A monotonic clock in ns that only moves when the test says so."""

    def __init__(self, start_ns: int = 1_000_000_000) -> None:
        self.now = start_ns

    def __call__(self) -> int:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += int(seconds * 1e9)


def wait_until(cond: Callable[[], bool], timeout: float = 3.0, step: float = 0.002) -> bool:
    """Poll ``cond`` until true or ``timeout`` seconds: for effects of other threads only,
    never for timing assertions."""
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            return False
        time.sleep(step)
    return True
