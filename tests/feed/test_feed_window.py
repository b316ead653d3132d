"""The feed thread's window (runtime/controller/window.py ``ScanWindow``) closes a quiet
time before the next scan's deadline, as the console's does: not a cycle after the last
scan's end, which leaves a scan that ended late in its cycle a quiet time shortened by
as much (at a 1 ms cycle, a scan ending 0.4 ms after its deadline left 0.1 ms of the
0.5 ms; the feed's publication then ran across the next deadline, bench.observers
--rounds)."""

from __future__ import annotations

import selectors
import socket
import time
from pathlib import Path

import pytest

from runtime.controller import feed as feed_module
from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.controller.window import ScanWindow
from runtime.language.plantfile import load_plant
from tests.opcua.kit import free_port, write_plant


@pytest.mark.parametrize("cycle", ["1ms", "10ms"])
def test_the_feeds_window_closes_a_quiet_time_before_the_next_deadline(
        tmp_path: Path, cycle: str) -> None:
    pdef = load_plant(str(write_plant(tmp_path, port=free_port(), cycle=cycle,
                                      sample="10ms")))
    d = Daemon(pdef, sim=True, manage_gc=False)  # not started: its deadline set by hand
    feed_def = pdef.feed()
    assert feed_def is not None
    fs = FeedServer(d, feed_def)
    window, cycle_s = fs.window, d.plant.cycle_ns / 1e9
    window.clock = lambda: 100.0  # a virtual clock, s: the scan ends at 100 s
    # a scan that ended 40 % into its cycle: the next deadline 60 % of a cycle away
    due = 100.0 + 0.6 * cycle_s
    d.scheduler.due = int(due * 1e9)
    window.on_scan(1)
    assert window.scan_end == 100.0
    assert window.closes == pytest.approx(due - window.quiet_s, abs=1e-9)


def _feed_with_one_client(tmp_path: Path, closes_in_s: float) -> tuple[FeedServer, list[str]]:
    """A FeedServer (not started) of a 10 ms plant with one client and a new snapshot to
    publish, its pieces recorded; its window closes ``closes_in_s`` from now."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port(), cycle="10ms")))
    d = Daemon(pdef, sim=True, manage_gc=False)
    feed_def = pdef.feed()
    assert feed_def is not None
    fs = FeedServer(d, feed_def)
    calls: list[str] = []
    for name in ("_publish", "_flush", "_serve", "_io"):
        def record(*_args: object, name: str = name) -> None:
            calls.append(name)
            fs._stop.set()  # one round
        setattr(fs, name, record)
    fs._clients = [object()]  # type: ignore[list-item]
    fs._slot = (0, 0.0, None, fs._cat, (), None)  # type: ignore[assignment]
    d.scheduler.due = int((time.monotonic() + fs.window.quiet_s + closes_in_s) * 1e9)
    fs.window.on_scan(1)
    return fs, calls


def test_nothing_of_a_feed_round_begins_after_its_window_closed(tmp_path: Path) -> None:
    """The image's read waits for the scan thread until the window closes at most: what
    is left of the round (the publication, the flush, the requests, the sockets) then
    waits for the next window. It was done in the quiet time before the next scan: a
    fifth of the publications and flushes began there at 1 ms (bench.observers
    --rounds), one ran across the deadline of an overrun."""
    fs, calls = _feed_with_one_client(tmp_path, 0.002)

    def image_until_closed(closes: float) -> None:
        calls.append("_write_image")
        while time.monotonic() < closes:  # the scan thread kept the state this long
            pass
        fs._stop.set()  # one round
    fs._write_image = image_until_closed  # type: ignore[method-assign]
    fs._run()
    assert calls == ["_write_image"]


def test_a_feed_round_in_an_open_window_does_all_its_pieces(tmp_path: Path) -> None:
    fs, calls = _feed_with_one_client(tmp_path, 60.0)
    fs._write_image = lambda closes: calls.append("_write_image")  # type: ignore[method-assign]
    fs._run()
    assert calls == ["_write_image", "_io", "_serve", "_publish", "_flush", "_io"]


def test_a_clients_image_request_is_served_before_the_publication(tmp_path: Path) -> None:
    """A side process says it reads the shared image (``{"image": true}``) as soon as it
    has the schema, and may then build its names for seconds without reading. A round
    serves what it sent before publishing: a whole frame queued to it meanwhile (its
    request read, not yet served) filled its small buffers, and the controller dropped
    it (tests/feed/test_poll.py, failed once in a full run)."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port(), cycle="10ms")))
    d = Daemon(pdef, sim=True, manage_gc=False)
    feed_def = pdef.feed()
    assert feed_def is not None
    fs = FeedServer(d, feed_def)
    fs._image = fs._new_image(fs._cat)
    assert fs._image is not None
    ours, theirs = socket.socketpair()
    ours.setblocking(False)
    theirs.setblocking(False)
    c = feed_module._Client(ours, "test")
    c.fresh = True
    c.inbuf += b'{"image": true}\n'  # read from its socket, not yet served
    fs._clients = [c]
    fs._sel = selectors.DefaultSelector()
    fs._copy = True  # it took frames when the scan copied the values
    fs.on_scan(fs._next)
    assert fs._slot is not None and fs._slot[2] is not None
    fs._write_image = lambda closes: None  # type: ignore[method-assign]
    # a virtual clock, s: the scan ends at 100 s, the window closes at 100.003 s
    fs.window = ScanWindow(0.010, clock=lambda: 100.0, due=d.next_scan_due)
    d.scheduler.due = int(100.008 * 1e9)
    fs.window.on_scan(1)
    try:
        fs._round()
        assert c.image
        sent = bytes(c.out)
        try:
            sent += theirs.recv(1 << 20)
        except BlockingIOError:
            pass
        assert b'{"f"' not in sent, sent[:200]
    finally:
        fs._sel.close()
        fs._image.retire()
        ours.close()
        theirs.close()
