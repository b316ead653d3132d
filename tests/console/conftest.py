"""Fixtures of the console tests: rigs that are always stopped, and a check that no test
leaves a softplc or console thread running."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest

from tests.console.consolekit import Rig, make_rig


@pytest.fixture(autouse=True)
def no_leaked_threads() -> Iterator[None]:
    before = set(threading.enumerate())
    yield
    end = time.monotonic() + 3.0
    while True:
        left = [t for t in threading.enumerate() if t not in before and t.is_alive()
                and t.name.startswith(("softplc-", "console", "test-null-modem"))]
        if not left or time.monotonic() > end:
            break
        time.sleep(0.01)
    assert not left, f"threads left running: {[t.name for t in left]}"


@pytest.fixture
def rigs() -> Iterator[Callable[..., Rig]]:
    """rigs(**make_rig options) -> a started Rig, stopped at the end of the test."""
    made: list[Rig] = []

    def make(**options: object) -> Rig:
        rig = make_rig(**options)  # type: ignore[arg-type]
        made.append(rig)
        return rig

    yield make
    for r in made:
        r.close()


@pytest.fixture
def rig(rigs: Callable[..., Rig]) -> Rig:
    """The default rig: trusted serial console and Unix socket, no PIN."""
    return rigs()
