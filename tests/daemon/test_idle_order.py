"""The windows of the threads that work beside the scan (the feed's, the console's) open
at the end of the scan thread's idle work, after the listeners, the queued calls, the
status and retain (issue 40). Opened from a listener in the middle of it, the woken
threads took the GIL from the rest of the idle work, which at a 1 ms cycle ran past the
next deadline: bench.observers, 10 testers, 843 of 1030 observed overruns; 37 of 125
with the windows opened last."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from runtime.controller.daemon import ScanCall
from runtime.controller.window import ScanWindow
from tests.daemon.daemonkit import MakeDaemon
from tests.opcua.feedkit import controller
from tests.opcua.kit import free_port


def test_what_is_added_last_runs_after_the_rest_of_the_idle_work(
        make_daemon: MakeDaemon) -> None:
    daemon, _ = make_daemon(start=False)
    seen: list[str] = []
    daemon.add_listener(lambda n: seen.append("opener"), last=True)
    daemon.add_listener(lambda n: seen.append("listener"))
    daemon._calls.append(ScanCall(lambda: seen.append("call")))
    daemon._idle(daemon.clock() + 10**9)
    assert seen == ["listener", "call", "opener"]


def windows(fns: tuple[Callable[[int], None], ...]) -> list[ScanWindow]:
    return [w for fn in fns if isinstance(w := getattr(fn, "__self__", None), ScanWindow)]


def test_the_feed_opens_its_window_last(tmp_path: Path) -> None:
    with controller(tmp_path, trace=False, port=free_port()) as (d, feed, _):
        assert windows(d._openers) == [feed.window]
        assert windows(d._listeners) == []
    assert d._openers == ()
