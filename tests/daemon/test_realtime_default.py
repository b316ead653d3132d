"""The scan thread runs SCHED_FIFO 50 by default where permitted (the installed service has
CAP_SYS_NICE): a scan at normal priority waits for the processor behind whatever else
runs, local users' programs included (issue 31: sixteen console clients at normal
priority made overruns in every run, once a watchdog fault). Where it is not permitted
(a controller started by hand by a user) it runs at normal priority and says so in one
information line; ``plc: realtime: false`` asks for normal priority."""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

import pytest

from runtime.controller import daemon as daemon_module
from runtime.controller.realtime import set_fifo_priority
from runtime.language.model import DEFAULT_REALTIME_PRIORITY
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import MakeDaemon, plant_yaml, wait_until


def fifo_permitted() -> bool:
    """Whether this process may make a thread SCHED_FIFO (tried on a thread of its own)."""
    got: list[bool] = []

    def attempt() -> None:
        got.append(set_fifo_priority(DEFAULT_REALTIME_PRIORITY)[0])
    t = threading.Thread(target=attempt)
    t.start()
    t.join()
    return got[0]


def scan_policy(d: daemon_module.Daemon) -> tuple[int, int]:
    assert d._thread is not None and d._thread.native_id is not None
    tid = d._thread.native_id
    return os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority


def test_the_scan_thread_is_real_time_by_default_where_permitted(
        make_daemon: MakeDaemon, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="runtime.controller.daemon")
    d, _ = make_daemon()
    wait_until(lambda: d.scan_stats.count > 2, what="a few cycles")
    lines = [r.getMessage() for r in caplog.records if "scan thread" in r.getMessage()]
    if fifo_permitted():
        assert scan_policy(d) == (os.SCHED_FIFO, DEFAULT_REALTIME_PRIORITY)
        assert lines == [f"scan thread at SCHED_FIFO priority {DEFAULT_REALTIME_PRIORITY}"]
    else:  # a user's run by hand
        assert scan_policy(d)[0] == os.SCHED_OTHER
        assert len(lines) == 1 and lines[0].startswith("scan thread at normal priority")


def test_where_it_is_refused_one_information_line_says_so(
        make_daemon: MakeDaemon, caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The default asked for and refused is no misconfiguration (a warning is kept for a
    priority the plant file asks for)."""
    monkeypatch.setattr(daemon_module, "set_fifo_priority", lambda prio: (
        False, f"not permitted (needs CAP_SYS_NICE or an RLIMIT_RTPRIO >= {prio}; the "
               "systemd unit grants it)"))
    caplog.set_level(logging.INFO, logger="runtime.controller.daemon")
    d, _ = make_daemon()
    wait_until(lambda: d.scan_stats.count > 2, what="a few cycles")
    (line,) = [r for r in caplog.records if "scan thread" in r.getMessage()]
    assert line.levelno == logging.INFO
    assert line.getMessage() == (
        "scan thread at normal priority (SCHED_FIFO not permitted (needs CAP_SYS_NICE or "
        "an RLIMIT_RTPRIO >= 50; the systemd unit grants it)): other processes can delay "
        "its scans")


def test_realtime_false_keeps_the_scan_thread_at_normal_priority(
        tmp_path: Path, make_daemon: MakeDaemon, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "plant.yaml"
    path.write_text(plant_yaml(realtime="false"), encoding="utf-8")
    assert load_plant(str(path)).realtime_priority == 0
    path.write_text(plant_yaml(), encoding="utf-8")
    assert load_plant(str(path)).realtime_priority is None  # the default
    caplog.set_level(logging.INFO, logger="runtime.controller.daemon")
    d, _ = make_daemon(realtime="false")
    wait_until(lambda: d.scan_stats.count > 2, what="a few cycles")
    assert scan_policy(d)[0] == os.SCHED_OTHER
    assert "scan thread at normal priority (plc: realtime: false)" in caplog.messages
