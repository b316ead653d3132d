"""The feed thread's window (runtime/controller/window.py ``ScanWindow``) closes a quiet
time before the next scan's deadline, as the console's does: not a cycle after the last
scan's end, which leaves a scan that ended late in its cycle a quiet time shortened by
as much (at a 1 ms cycle, a scan ending 0.4 ms after its deadline left 0.1 ms of the
0.5 ms; the feed's publication then ran across the next deadline, bench.observers
--rounds)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
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
    # a scan that ended 40 % into its cycle: the next deadline 60 % of a cycle away
    due = time.monotonic() + 0.6 * cycle_s
    d.scheduler.due = int(due * 1e9)
    window.on_scan(1)
    assert window.closes == pytest.approx(due - window.quiet_s, abs=1e-9)
    assert window.closes - window.scan_end < cycle_s - window.quiet_s


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
    assert calls == ["_write_image", "_publish", "_flush", "_serve", "_io"]
