"""A console stream lets go of the images it will not compare one at a time (issue 40).

Found with `bench.observers` at 100 testers: the scan waited 40-56 ms for the GIL while
the console's socket thread, at the end of a trace poll, freed the images queued beyond
the newest STREAM_LINES_PER_POLL (up to STREAM_SCANS of them, some 200 000 objects) in one
C-level cascade of deallocations, during which no other thread can take the GIL (perf:
`tupledealloc` all through the stall). The same happened when a lagging stream ended.
Since then the scan thread keeps no more than the newest STREAM_LINES_PER_POLL (and the
start's snapshot) for a stream: the third test.

Counted, not timed: each image carries an object whose finalizer notes how many lines of
Python the freeing thread had run by then (a trace function counts them, the finalizer's
own excepted). Images freed with no line run between them were freed in one stretch."""

from __future__ import annotations

import dataclasses
import sys
import threading
from collections.abc import Callable
from types import FrameType, SimpleNamespace
from typing import Any

from runtime.console import streams
from runtime.console.protocol import STREAM_LINES_PER_POLL
from runtime.console.streams import Stream
from runtime.engine.names import Image, Signal
from runtime.language import ast as A
from tests.console.consolekit import Rig, wait_for

#: images queued in a lagging stream, in these tests
QUEUED = 400


class Counter:
    """The lines of Python run by the threads it traces (``sys.settrace``), and the
    frees noted by Freed: (thread, lines run by then)."""

    def __init__(self) -> None:
        self.lines = 0
        self.freed: list[tuple[int, int]] = []

    def trace(self, frame: FrameType, event: str, arg: Any) -> Any:
        if event == "call" and frame.f_code in (Freed.__del__.__code__,
                                                FreedInt.__del__.__code__):
            return None  # the finalizer's own lines are not the freeing code's
        if event == "line":
            self.lines += 1
        return self.trace

    def longest_stretch(self, thread: int) -> int:
        """The most images ``thread`` freed with no line of Python between them."""
        runs: dict[int, int] = {}
        for t, n in self.freed:
            if t == thread:
                runs[n] = runs.get(n, 0) + 1
        return max(runs.values(), default=0)


class Freed:
    """An object whose finalizer notes its free."""

    def __init__(self, counter: Counter) -> None:
        self.counter = counter

    def __del__(self) -> None:
        self.counter.freed.append((threading.get_ident(), self.counter.lines))


def marked(img: Image, counter: Counter) -> Image:
    return dataclasses.replace(img, ok=(*img.ok, Freed(counter)))  # type: ignore[arg-type]


def test_a_poll_lets_go_of_the_images_it_skips_one_at_a_time() -> None:
    x = Signal("p.rX", A.Type.REAL, lambda img: img.m[0][0], "memory", spec=("slot", 0, 0))
    cat = SimpleNamespace(names={"p.rX": x})
    counter = Counter()
    stream = Stream("trace", [x], cat)  # type: ignore[arg-type]
    stream.images.append(marked(Image(-1, [[0]], [], [], []), counter))  # type: ignore[list-item]
    stream.poll(lambda: 0.0, False)
    assert len(counter.freed) == 1  # the snapshot, once read
    counter.freed.clear()
    stream.last_scan = 0  # as begin() sets it
    stream.images.extend(marked(Image(scan, [[scan]], [], [], []), counter)  # type: ignore[list-item]
                         for scan in range(1, QUEUED + 1))
    sys.settrace(counter.trace)
    try:
        lines = stream.poll(lambda: 0.0, False)
    finally:
        sys.settrace(None)
    # the newest STREAM_LINES_PER_POLL compared, the scans before them said not shown
    assert len(lines) == STREAM_LINES_PER_POLL
    first = QUEUED - STREAM_LINES_PER_POLL + 1
    assert lines[0] == (f"trace {first} ({first - 1} scans not shown: the line is too "
                        f"slow): p.rX={first}")
    assert len(counter.freed) == QUEUED and not stream.images  # every image let go
    # the skipped ones one at a time; the ones compared go together as the poll ends
    # (before: all QUEUED in one stretch)
    assert counter.longest_stretch(threading.get_ident()) <= STREAM_LINES_PER_POLL


def test_a_stream_nobody_polls_keeps_the_snapshot_and_the_newest_scans_only(
        rigs: Callable[..., Rig]) -> None:
    """No poll compares more than the newest STREAM_LINES_PER_POLL images, so the scan
    thread keeps no more (before: up to STREAM_SCANS, kept alive until the poll: at a
    1 ms cycle the scan thread then ran a young garbage collection about ten times a
    second, 0.5 ms each). The start's snapshot stays first until a poll reads it; the
    scans dropped are counted in the next line."""
    rig = rigs(serial_port=False, unix_socket=False, blink=True)
    s = rig.service.session("tracer")
    try:
        assert s.feed(b"trace on\r\n")[-1] == "ok"
        stream = s.stream
        assert stream is not None
        first = wait_for(lambda: stream.images[-1].scan if len(stream.images) > 1 else None,
                         "a scan queued")
        wait_for(lambda: stream.images[-1].scan >= first + 3 * STREAM_LINES_PER_POLL,
                 "three polls' worth of scans")
        # read between two scans (in the scan thread's idle work): as a scan left it
        queued = rig.daemon.call(lambda: list(stream.images))
        assert len(queued) == STREAM_LINES_PER_POLL + 1, [i.scan for i in queued]
        assert queued[0].scan == -1  # the snapshot
        scans = [i.scan for i in queued[1:]]
        assert scans == list(range(scans[0], scans[0] + STREAM_LINES_PER_POLL)), scans
        assert scans[0] > first + STREAM_LINES_PER_POLL
        lines = stream.poll(lambda: 0.0, False)
        assert lines and "scans not shown" in lines[0], lines
    finally:
        s.close()


def test_a_stream_that_ends_lets_go_of_its_queued_images_one_at_a_time(
        rigs: Callable[..., Rig], monkeypatch: Any) -> None:
    """A trace nobody polls queues an image per scan (the newest STREAM_LINES_PER_POLL
    and the snapshot); the line that ends it frees them in the session's thread, one at
    a time."""
    rig = rigs(serial_port=False, unix_socket=False, blink=True)
    cat = rig.service.catalogue
    counter = Counter()
    capture = cat.capture
    monkeypatch.setattr(cat, "capture", lambda scan: marked(capture(scan), counter))
    s = rig.service.session("tracer")
    try:
        assert s.feed(b"trace on\r\n")[-1] == "ok"
        stream = s.stream
        assert stream is not None
        wait_for(lambda: len(stream.images) > STREAM_LINES_PER_POLL, "the scans queued")
        queued_at_least = len(stream.images)
        freed_before = len(counter.freed)  # those the scan thread let go
        sys.settrace(counter.trace)
        try:
            s.feed(b"\r")  # any line ends the stream
        finally:
            sys.settrace(None)
        me = threading.get_ident()
        assert s.stream is None
        mine = [f for f in counter.freed[freed_before:] if f[0] == me]
        assert len(mine) >= queued_at_least - 1
        assert counter.longest_stretch(me) <= 1
    finally:
        s.close()


class FreedInt(int):
    """An int whose finalizer notes its free (a value a counter takes)."""

    counter: Counter

    def __del__(self) -> None:
        self.counter.freed.append((threading.get_ident(), self.counter.lines))


def test_the_texts_a_stream_keeps_go_a_few_at_a_time_when_there_are_too_many(
        monkeypatch: Any) -> None:
    """A counter counting fills the stream's texts of (name, value) pairs. They were
    kept together, up to PARTS_KEPT, and cleared at once (20 000 texts held the GIL
    about 3.5 ms: a profile of the console thread in bench.observers); then one at a
    time. Now each name keeps its own, at most TEXTS_PER_NAME's upper bound (lowered to 8
    here), and a counter's go together: 8 at most."""
    monkeypatch.setattr(streams, "TEXTS_PER_NAME", (2, 8))
    x = Signal("p.iN", A.Type.INT, lambda img: img.m[0][0], "memory", spec=("slot", 0, 0))
    cat = SimpleNamespace(names={"p.iN": x})
    counter = Counter()
    FreedInt.counter = counter
    stream = Stream("trace", [x], cat)  # type: ignore[arg-type]
    stream.images.append(Image(-1, [[FreedInt(-1)]], [], [], []))  # type: ignore[list-item]
    stream.last_scan = 0
    shown = 0
    sys.settrace(counter.trace)
    try:
        for first in range(1, 200, 10):  # ten scans a poll: none skipped
            stream.images.extend(Image(scan, [[FreedInt(scan)]], [], [], [])  # type: ignore[list-item]
                                 for scan in range(first, first + 10))
            shown += len(stream.poll(lambda: 0.0, False))
    finally:
        sys.settrace(None)
    assert shown == 200
    assert len(counter.freed) > 100  # the counter's old values went with their texts
    # before: 51 at a time (the texts cleared at once, PARTS_KEPT lowered to 50)
    # now a name's 8 texts, and with them a value the images let go (9 measured; 15 with
    # the bound at 16)
    assert counter.longest_stretch(threading.get_ident()) <= 8 + 1
