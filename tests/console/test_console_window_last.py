"""The console opens its window at the end of the scan thread's idle work, as the feed
does (tests/daemon/test_idle_order.py says why)."""

from __future__ import annotations

from collections.abc import Callable

from tests.console.consolekit import Rig
from tests.daemon.test_idle_order import windows


def test_the_console_opens_its_window_last(rigs: Callable[..., Rig]) -> None:
    rig = rigs(serial_port=False)  # a Unix socket: a transport, so a window
    server = rig.server
    assert windows(rig.daemon._openers) == [server.window]
    assert windows(rig.daemon._listeners) == []
