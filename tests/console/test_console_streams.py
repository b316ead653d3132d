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
        start = rig.daemon.scan_stats.count
        # (the stream keeps the newest STREAM_LINES_PER_POLL: the scans since it started
        # are counted on the controller)
        wait_for(lambda: rig.daemon.scan_stats.count > start + 3 * STREAM_LINES_PER_POLL,
                 "60 cycles")
        before = rig.daemon.scan_stats.count
        lines = session.poll()
        after = rig.daemon.scan_stats.count
        # the newest STREAM_LINES_PER_POLL cycles, one line each that changed: all of them
        # with the blinking lamp, but the first kept shows no change when it is an even
        # number of scans after the last one shown (how many scans the poll finds depends
        # on the machine's load: a loaded run found 19 lines, and the count of the scans
        # not shown went with the line that showed nothing)
        assert len(lines) in (STREAM_LINES_PER_POLL - 1, STREAM_LINES_PER_POLL), lines
        m = re.match(r"trace (\d+) \((\d+) scans not shown: the line is too slow\): ", lines[0])
        assert m and int(m.group(2)) > 2 * STREAM_LINES_PER_POLL - 2, lines[0]
        scans = [int(re.match(r"trace (\d+)", x).group(1)) for x in lines]  # type: ignore[union-attr]
        assert scans == list(range(scans[0], scans[0] + len(lines)))
        # the newest image at the poll (the cycle counted just before may not be captured)
        assert before - 1 <= scans[-1] <= after, (before, scans[-1], after)
        lamp = [x.split("b1.oLamp=")[1][0] for x in lines]
        assert all(a != b for a, b in zip(lamp, lamp[1:], strict=False)), lamp
        session.feed(b"\r")
        assert session.stream is None
    finally:
        session.close()


def test_the_count_of_scans_not_shown_goes_with_the_next_line_shown() -> None:
    """The first image kept by a poll may show no change from the last line (a lamp
    blinking every scan, seen an even number of scans later): the count of the scans not
    shown goes with the next line. Before, it went with the line that was never written,
    and a reader saw the scans jump with no word."""
    from types import SimpleNamespace

    from runtime.console.streams import Stream
    from runtime.engine.names import Image, Signal
    from runtime.language import ast as A

    lamp = Signal("b1.oLamp", A.Type.BOOL, lambda img: bool(img.m[0][0]), "output")
    cat = SimpleNamespace(names={"b1.oLamp": lamp})

    def image(scan: int) -> Image:
        return Image(scan, [[scan % 2 == 1]], [], [], [])  # type: ignore[list-item]

    def started(last: int) -> list[str]:
        """A trace started after scan 10 (lamp off), scans 11..``last`` queued since."""
        stream = Stream("trace", [lamp], cat)  # type: ignore[arg-type]
        stream.images.append(Image(-1, [[False]], [], [], []))  # type: ignore[list-item]
        stream.last_scan = 10
        for scan in range(11, last + 1):
            stream.images.append(image(scan))
        return stream.poll(lambda: 0.0, False)

    # the poll keeps the newest STREAM_LINES_PER_POLL, 43..62: 43 (lamp on) changed
    lines = started(62)
    assert lines[0] == "trace 43 (32 scans not shown: the line is too slow): b1.oLamp=1"
    assert len(lines) == STREAM_LINES_PER_POLL
    # one scan more: 44..63 kept, 44 equal to the last shown
    lines = started(63)
    # scan 44 (lamp off, as at the start) shows nothing; 45 carries the count of 11..43
    assert lines[0] == "trace 45 (33 scans not shown: the line is too slow): b1.oLamp=1"
    assert len(lines) == STREAM_LINES_PER_POLL - 1
