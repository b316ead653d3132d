"""bench/opcua.py measures the scan in a window without stopping what the OPC UA server
shows: an alarm raised and cleared while a window measures reaches the feed (the
server's source) as it would without the window. (The window used to reset the daemon's
scan statistics; the feed and the alarm board pace themselves on their count of scans,
so both stopped for as many scans as had run before: bench.opcua counted no alarm event
at all, and the server showed every value BadOutOfService.)"""

from __future__ import annotations

import threading
from functools import partial
from pathlib import Path
from typing import Any

from bench.opcua import opcua_plant, start_daemon, stop_daemon, window
from tests.opcua.feedkit import FeedReader, wait_until
from tests.opcua.kit import free_port

#: scans the controller runs before the window (at 10 ms: 10 s); the old reset stopped
#: the alarm board and the feed for as many scans, at least this long
BEFORE = 1000
#: how long an alarm may take to reach the feed, seconds: the board looks every 50 ms of
#: scans, the feed sends every sample (50 ms); generous for a loaded machine, and half of
#: what the old reset stopped them for
SHOWN_S = 5.0


def test_an_alarm_reaches_the_feed_while_a_window_measures(tmp_path: Path) -> None:
    path = opcua_plant(str(tmp_path), 2, free_port(), False, None, clients=1)
    d, fs = start_daemon(path, 2, True)
    feed = FeedReader(str(tmp_path / "feed.sock"))
    measured: dict[str, Any] = {}
    started = threading.Event()

    def measure() -> None:
        started.set()
        measured.update(window(d, 2 * SHOWN_S + 2))
    thread = threading.Thread(target=measure)
    try:
        stats = d.scan_stats
        wait_until(lambda: stats.count >= BEFORE, 60.0, f"{BEFORE} scans")
        if d.fault is not None:  # a freeze of the loaded machine: the charts run again
            d.ack()
        thread.start()
        started.wait(10)
        plant = d.plant

        def sent(active: bool) -> bool:
            last = feed.statuses[-1] if feed.statuses else {}
            return any(a["key"] == "t0.SFCError" and bool(a["active"]) is active
                       for a in (last.get("alarms") or []))
        d.call(partial(plant.set, "t0.SFCError", True))
        wait_until(partial(sent, True), SHOWN_S, "t0.SFCError raised, in the feed")
        d.call(partial(plant.pulse, "t0", "SFCQuitError"))
        wait_until(partial(sent, False), SHOWN_S, "t0.SFCError cleared, in the feed")
        thread.join(60)
        # the window measured the scans it saw, and the count of scans went on
        assert measured["cycles"] > 0, measured
        assert stats.count >= BEFORE + measured["cycles"], (stats.count, measured)
    finally:
        feed.close()
        if thread.is_alive():
            thread.join(60)
        stop_daemon(d, fs)
