"""Streams on a line that cannot keep up: cycles are skipped and counted, never queued
without bound, and the last values shown are never wrong."""

from __future__ import annotations

import re
from collections.abc import Callable

from runtime.console.protocol import STREAM_LINES_PER_POLL
from tests.console.consolekit import Rig, wait_for


def test_a_slow_reader_gets_the_latest_scans_and_a_count_of_the_others(
        rigs: Callable[..., Rig]) -> None:
    rig = rigs(serial_port=False, unix_socket=False, blink=True)
    session = rig.service.session("slow reader")  # a session whose line is not read
    try:
        assert session.feed(b"trace on\r\n")[-1] == "ok"
        stream = session.stream
        assert stream is not None
        wait_for(lambda: len(stream.images) > 3 * STREAM_LINES_PER_POLL, "60 cycles")
        before = rig.daemon.scan_stats.count
        lines = session.poll()
        after = rig.daemon.scan_stats.count
        assert len(lines) == STREAM_LINES_PER_POLL
        m = re.match(r"trace (\d+) \((\d+) scans not shown: the line is too slow\): ", lines[0])
        assert m and int(m.group(2)) > 2 * STREAM_LINES_PER_POLL - 2, lines[0]
        # the newest cycles, one line each, the blinking lamp alternating
        scans = [int(re.match(r"trace (\d+)", x).group(1)) for x in lines]  # type: ignore[union-attr]
        assert scans == list(range(scans[0], scans[0] + STREAM_LINES_PER_POLL))
        # the newest image at the poll (the cycle counted just before may not be captured)
        assert before - 1 <= scans[-1] <= after, (before, scans[-1], after)
        lamp = [x.split("b1.oLamp=")[1][0] for x in lines]
        assert all(a != b for a, b in zip(lamp, lamp[1:], strict=False)), lamp
        session.feed(b"\r")
        assert session.stream is None
    finally:
        session.close()
