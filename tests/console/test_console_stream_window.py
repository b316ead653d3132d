"""The streams' work keeps to the console's windows (issue 40): a poll of the ``trace``
streams stops when its window closes and goes on in the next one, whatever the number of
streams and images queued. Before, one poll of every stream compared up to
STREAM_LINES_PER_POLL images each in one stretch: with four traces of 100 testers (3901
names) a poll took up to 200 ms of wall time, holding the GIL across the quiet time and
the scan's wake-ups (bench.observers: the scan's wake-ups blocked 0.7 ms at the 99th
percentile, the console's socket thread caught comparing images at nearly every late
one)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

import pytest

from runtime.console.protocol import STREAM_LINES_PER_POLL
from runtime.console.server import OUT_MAX, Line
from runtime.console.streams import Changes, Stream
from runtime.engine.names import Catalogue
from tests.console.consolekit import Rig, wait_for
from tests.console.test_console_stream_cost import drawers_plant

#: what comparing one image costs in these tests, s (a few hundred µs to ms on a
#: Raspberry Pi-class core at 100 testers)
SLOW_S = 0.002
#: the trace streams of the server test
STREAMS = 4


def test_a_poll_stops_when_told_and_the_next_one_goes_on_where_it_stopped(
        write: Callable[[str, str], str], drawer: str) -> None:
    """A trace whose poll may compare two images: those left are compared by the next
    poll, in order; the lines of the polls together are those of one poll of all."""
    plant = drawers_plant(write)
    cat = Catalogue(plant)

    def stream_with_images() -> Stream:
        for k in range(6):
            plant.set(f"sim.I{1 + 8 * k}", 0)
        s = Stream("trace", cat.traced, cat)
        s.images.append(cat.capture(-1))
        s.last_scan = 2
        assert s.poll(lambda: 0.0, False) == []
        for k in range(6):
            plant.set(f"sim.I{1 + 8 * k}", 1)  # a tester's iMarcha
            s.images.append(cat.capture(3 + k))
        return s

    whole = stream_with_images().poll(lambda: 0.0, False)
    assert len(whole) == 6

    s = stream_with_images()
    asked: list[int] = []

    def two() -> bool:
        asked.append(1)
        return len(asked) <= 2
    first = s.poll(lambda: 0.0, False, two)
    assert first == whole[:2] and s.behind
    asked.clear()
    assert s.poll(lambda: 0.0, False, two) == whole[2:4]
    asked.clear()
    assert s.poll(lambda: 0.0, False) == whole[4:] and not s.behind


def test_trace_streams_compare_images_inside_the_windows_only(
        rigs: Callable[..., Rig], monkeypatch: pytest.MonkeyPatch) -> None:
    """STREAMS clients stream ``trace on`` while comparing an image costs SLOW_S: the
    images the console begins to compare after its window has closed (in the quiet time
    before a scan, or during it) are at most one a window, and every stream is served.
    Before, a poll compared its images in one stretch: 110 of 202 images were begun after
    their window closed, 2 or 3 a window."""
    rig = rigs()
    window = rig.server.window
    began: list[tuple[float, float, int]] = []  # (when, the window's close then, stream)
    lock = threading.Lock()
    compare = Changes.changed

    def slow(self: Changes, img: Any) -> list[int]:
        with lock:
            began.append((time.monotonic(), window.closes, id(self)))
        end = time.perf_counter() + SLOW_S
        while time.perf_counter() < end:
            pass
        return compare(self, img)

    monkeypatch.setattr(Changes, "changed", slow)
    clients = [rig.connect() for _ in range(STREAMS)]
    for c in clients:
        c.ok("trace on")
    # enough for each stream to have had images compared in several windows
    wait_for(lambda: len({s for _, _, s in began}) == STREAMS and len(began) > 200,
             "every stream's images compared", timeout=60.0)
    with lock:
        seen = list(began)
    late: dict[float, int] = {}
    for when, closes, _ in seen:
        if when >= closes:
            late[closes] = late.get(closes, 0) + 1
    assert max(late.values(), default=0) <= 1, (
        f"{sum(late.values())} of {len(seen)} images begun after their window closed, "
        f"up to {max(late.values())} in one window")
    assert STREAM_LINES_PER_POLL > 1  # a poll may have several images to compare


def test_a_peer_behind_with_its_replies_counts_as_polled(rig: Rig) -> None:
    """A stream cut short by its window, whose peer then stops reading: its poll is done
    for this tick (its images wait in its queue). Before, it said "not done", and the tick
    polled it again and again until the window's time was spent."""
    session = rig.service.session("test", trusted=True)
    cat = rig.service.catalogue
    stream = Stream("trace", cat.traced, cat)
    stream.images.append(cat.capture(-1))
    assert stream.poll(lambda: 0.0, False) == []
    stream.images.append(cat.capture(1))
    stream.images.append(cat.capture(2))
    assert stream.poll(lambda: 0.0, False, lambda: False) == [] and stream.behind
    session.stream = stream
    line = Line(session, time.monotonic)
    line.out += b"x" * OUT_MAX
    assert line.poll(time.monotonic() + 60.0) is True
    assert stream.behind  # nothing compared meanwhile
