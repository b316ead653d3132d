"""The threads that work beside a real-time scan in its windows run real time below it
(issue 40): a console thread holding the GIL when the scan was due had been taken off the
processor by the machine while it held it, and the scan woke 20 to 40 ms late once a
minute with every observer connected (bench.observers --who: the console's socket thread
caught formatting a stream's lines). At SCHED_FIFO 1 such a thread runs until it lets go
of the GIL, whatever else the machine runs; beside a scan at normal priority they stay at
normal priority too (never above the scan)."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.controller.daemon import HELPER_PRIORITY
from runtime.controller.window import ScanWindow
from tests.console.consolekit import Rig, wait_for
from tests.console.test_console_flood import fifo_permitted
from tests.opcua.feedkit import FeedReader, controller, wait_until

needs_fifo = pytest.mark.skipif(not fifo_permitted(), reason="SCHED_FIFO is not permitted "
                                "here (not root, no CAP_SYS_NICE): CI runs as root")


def policy(t: threading.Thread) -> tuple[int, int]:
    """(scheduling policy, priority) of a running thread."""
    assert t.native_id is not None
    return os.sched_getscheduler(t.native_id), os.sched_getparam(t.native_id).sched_priority


def console_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name.startswith("console-")]


@needs_fifo
def test_console_threads_run_real_time_below_a_real_time_scan(
        rigs: Callable[..., Rig]) -> None:
    rig = rigs(priority=50)
    c = rig.connect()
    c.ok("status")  # the socket thread has worked in a window
    scan = next(t for t in threading.enumerate() if t.name == "softplc-scan")
    assert policy(scan) == (os.SCHED_FIFO, 50)
    threads = console_threads()
    assert threads
    wait_for(lambda: all(policy(t) == (os.SCHED_FIFO, HELPER_PRIORITY) for t in threads),
             "every console thread at SCHED_FIFO 1")


@needs_fifo
def test_console_threads_stay_at_normal_priority_beside_a_normal_scan(
        rigs: Callable[..., Rig]) -> None:
    rig = rigs(priority=0)
    c = rig.connect()
    c.ok("status")
    assert rig.daemon.helper_priority is None
    assert all(policy(t)[0] == os.SCHED_OTHER for t in console_threads())


@needs_fifo
def test_a_thread_takes_the_priority_once_it_is_known() -> None:
    """The first windows come before the scan thread is real time (nothing known yet):
    the thread is raised at the first window after."""
    known: list[int | None] = [None]
    w = ScanWindow(0.010, priority=lambda: known[0])
    seen: list[tuple[int, int]] = []

    def work() -> None:
        w.on_scan(0)
        w.slot()
        seen.append(policy(threading.current_thread()))
        known[0] = HELPER_PRIORITY
        w.on_scan(1)
        w.slot()
        seen.append(policy(threading.current_thread()))
    t = threading.Thread(target=work)
    t.start()
    t.join(10)
    assert seen == [(os.SCHED_OTHER, 0), (os.SCHED_FIFO, HELPER_PRIORITY)]


@needs_fifo
def test_the_feed_thread_runs_real_time_below_a_real_time_scan(tmp_path: Path) -> None:
    """The feed (the side processes' thread in the controller) follows the same rule."""
    with controller(tmp_path, trace=False) as (d, feed, _):
        reader = FeedReader(feed.path)
        try:
            wait_until(lambda: reader.schemas > 0, what="the schema")
            thread = next(t for t in threading.enumerate() if t.name == "softplc-feed")
            wait_until(lambda: policy(thread) == (os.SCHED_FIFO, HELPER_PRIORITY),
                       what="the feed thread at SCHED_FIFO 1")
            assert d.helper_priority == HELPER_PRIORITY
        finally:
            reader.close()
