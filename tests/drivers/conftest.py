"""Fixtures of the driver tests: an injected clock, and a check that no test leaks threads
or open terminals (pymodbus' ``system_health_check`` idea)."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator

import pytest

from tests.drivers.drvkit import FakeClock


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


def _tty_fds() -> set[str]:
    out: set[str] = set()
    try:
        names = os.listdir("/proc/self/fd")
    except OSError:  # pragma: no cover - not Linux
        return out
    for fd in names:
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(("/dev/pts/", "/dev/ptmx", "/dev/tty")):
            out.add(f"{fd}->{target}")
    return out


@pytest.fixture(autouse=True)
def system_health_check() -> Iterator[None]:
    """Fail a test that leaves a thread running or a terminal open behind it."""
    threads = set(threading.enumerate())
    ttys = _tty_fds()
    yield
    deadline = time.monotonic() + 2.0
    leaked: list[threading.Thread] = []
    while time.monotonic() < deadline:
        leaked = [t for t in threading.enumerate() if t not in threads and t.is_alive()]
        if not leaked:
            break
        time.sleep(0.01)
    assert not leaked, f"threads left running: {[t.name for t in leaked]}"
    left = _tty_fds() - ttys
    assert not left, f"terminals left open: {sorted(left)}"
