"""systemd's WATCHDOG=1 comes every half WatchdogSec whatever the cycle time, and stops
only while the scan thread is stuck: a real controller with a 1.5 s cycle against a real
AF_UNIX datagram socket as $NOTIFY_SOCKET; a stuck scan in-process."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.controller.scheduler import Scheduler, Watchdog
from tests.daemon.test_daemon_process import NotifySocket, plant, start, stop
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

MS = 1_000_000


@pytest.fixture
def line() -> Iterator[tuple[PtyBridge, ModbusPeer]]:
    with PtyBridge() as bridge, ModbusPeer(bridge.peer_port, (1,)) as peer:
        yield bridge, peer


def test_pings_keep_coming_at_half_watchdogsec_with_a_long_cycle(
        tmp_path: Path, line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, _ = line
    notify = NotifySocket(tmp_path / "notify.sock")
    # WatchdogSec=1s: pings due every 500 ms; the cycle is longer than WatchdogSec
    proc = start(plant(tmp_path, bridge.driver_port, cycle="1500ms", tolerant=True),
                 {"NOTIFY_SOCKET": notify.path, "WATCHDOG_USEC": "1000000"})
    try:
        notify.wait_for("READY=1", timeout=30)
        notify.collect(4.0)  # a time span of several cycles, not a count of pings
    finally:
        code, err = stop(proc)
        notify.close()
    assert code == 0, err
    ready = next(t for t, m in notify.messages if m.startswith("READY=1"))
    pings = [t for t, m in notify.messages if m == "WATCHDOG=1" and t >= ready]
    # pings tied to the 1.5 s cycle would be 3 in the 4 s; every 0.5 s, 8 or 9
    assert len(pings) >= 6, notify.messages
    gaps = [b - a for a, b in zip(pings, pings[1:], strict=False)]
    # systemd kills at 1 s without a ping; the pings are due every 0.5 s. They are timed
    # as this process receives them: one pause of it (or of the machine) may stretch one
    # gap; pings tied to the cycle stretch every gap to 1.5 s
    assert len([g for g in gaps if g >= 0.9]) <= 1, gaps


def test_a_stuck_scan_stops_the_pings_and_they_resume_after_it() -> None:
    release, entered = threading.Event(), threading.Event()
    pings: list[float] = []
    hang = [False]

    def body(now: int) -> None:
        if hang[0]:
            hang[0] = False
            entered.set()
            release.wait(30)

    s = Scheduler(body, 20 * MS, 100 * MS, manage_gc=False)
    wd = Watchdog(s, 100 * MS, lambda ns: None, ping=lambda: pings.append(time.monotonic()),
                  ping_interval_ns=25 * MS)
    t = threading.Thread(target=s.run, name="softplc-test-scan")
    wd.start()
    t.start()
    try:
        end = time.monotonic() + 30
        while len(pings) < 3 and time.monotonic() < end:
            time.sleep(0.005)
        assert len(pings) >= 3, "no pings while healthy"
        hang[0] = True
        assert entered.wait(30)
        t_hang = time.monotonic()
        time.sleep(1.0)  # the attack: the scan stays stuck for ten watchdog times
        during = [p for p in pings if p > t_hang + 0.3]  # stuck well beyond the watchdog
        assert during == [], "pinged while the scan was stuck"
        release.set()
        n = len(pings)
        end = time.monotonic() + 30
        while len(pings) <= n and time.monotonic() < end:
            time.sleep(0.005)
        assert len(pings) > n, "the pings did not resume after the scan"
    finally:
        release.set()
        s.stop_event.set()
        t.join(10)
        wd.stop()
