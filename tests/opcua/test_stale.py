"""Stale values turn bad (issue 31): a controller frozen by SIGSTOP, or stuck in one scan
while its watchdog has switched the outputs off, sends no frame; the server's values must
not stay Good with a frozen SourceTimestamp. Within the documented bound (docs/opcua.md,
"Stale values": no frame for max(4 x sample, 1 s), checked every sample) every variable
reads BadOutOfService (without a value: a Bad value carries none, Part 4 7.7.1), with
the last frame's SourceTimestamp; Good again with the next frame."""

from __future__ import annotations

import asyncio
import datetime
import logging
import os
import signal
import socket
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua

import runtime.controller.feed as feed_module
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import RecordingDriver
from tests.opcua.feedkit import ServerThread, serving, until, wait_until
from tests.opcua.kit import end, free_port, softplc, write_plant

#: the documented bound at the plants' sample (50 ms): max(4 x 50 ms, 1 s), plus one check
#: period (the sample)
BOUND_S = 1.0 + 0.05
#: what a loaded test machine may add to it (the server's event loop, a publish, a pause
#: of this process: the server runs in it; CI saw one of 769 ms), s. Values never made
#: stale, the defect, are unbounded
SLACK_S = 2.0
WATCHED = ("t1.sN", "t1.oLamp", "controller.state", "controller.scans", "io.Q0")


class Changes:
    """Every data change received: (name, DataValue, the time it was received)."""

    def __init__(self) -> None:
        self.items: list[tuple[str, ua.DataValue, float]] = []

    def datachange_notification(self, node: Any, val: Any, data: Any) -> None:
        self.items.append((node.nodeid.Identifier, data.monitored_item.Value, time.time()))

    def last(self, name: str) -> ua.DataValue | None:
        for n, dv, _ in reversed(self.items):
            if n == name:
                return dv
        return None

    def all_are(self, status: str) -> bool:
        last = [self.last(n) for n in WATCHED]
        return all(dv is not None and dv.StatusCode.name == status for dv in last)

    def statuses(self) -> str:
        """Each watched name's last status (or none received), for a failure's message."""
        last = {n: self.last(n) for n in WATCHED}
        return ", ".join(f"{n}: {'none' if dv is None else dv.StatusCode.name}"
                         for n, dv in last.items()) + f" ({len(self.items)} changes)"


def _ts(dt: datetime.datetime | None) -> float:
    assert dt is not None
    return dt.replace(tzinfo=datetime.UTC).timestamp() if dt.tzinfo is None else dt.timestamp()


def first_frame(srv: ServerThread) -> None:
    """Wait for the server's first frame: the plant's variables are built from the feed's
    schema after the server has started (its fixed part only); subscribed before, they
    are BadNodeIdUnknown and never notified (a CI run: 402 changes of the controller's
    two, none of the plant's three, "good values" timed out)."""
    wait_until(lambda: srv.ps is not None and srv.ps.frames > 0, 30.0, "a first frame")


async def _watch_a_stall(url: str, stall: Any, resume: Any) -> tuple[float, dict[str, Any]]:
    """Subscribe to WATCHED, call ``stall()`` once every value is good, wait for every
    value to turn BadOutOfService, ``resume()``, wait for Good again; (how long after the
    last good frame the values turned bad by the server's clock, the bad DataValues)."""
    changes = Changes()
    async with Client(url, timeout=30) as c:
        sub = await c.create_subscription(100, changes)
        handles = await sub.subscribe_data_change(
            [c.get_node(f"ns=2;s={n}") for n in WATCHED], queuesize=100)
        # a node not yet in the address space is a StatusCode here, and never notified
        assert all(isinstance(h, int) for h in handles), dict(zip(WATCHED, handles,
                                                                  strict=True))
        await until(lambda: changes.all_are("Good"), 20,
                    lambda: f"good values: {changes.statuses()}")
        stall()
        await until(lambda: changes.all_are("BadOutOfService"), 30,
                    lambda: f"every value BadOutOfService: {changes.statuses()}")
        bad = {n: changes.last(n) for n in WATCHED}
        resume()
        await until(lambda: changes.all_are("Good"), 30,
                    lambda: f"good values again: {changes.statuses()}")
        await sub.delete()
    scans = bad["controller.scans"]
    assert scans is not None
    # the stale value has the last frame's SourceTimestamp and no value; its
    # ServerTimestamp is when the server decided it was stale
    good = [dv for n, dv, _ in changes.items
            if n == "controller.scans" and dv.StatusCode.is_good()
            and _ts(dv.ServerTimestamp) < _ts(scans.ServerTimestamp)]
    assert good[-1].SourceTimestamp == scans.SourceTimestamp
    assert all(dv is not None and dv.Value.Value is None for dv in bad.values())
    delay = _ts(scans.ServerTimestamp) - _ts(scans.SourceTimestamp)
    return delay, bad


def test_a_controller_stopped_by_sigstop_turns_every_value_bad(tmp_path: Path) -> None:
    port = free_port()
    plant = write_plant(tmp_path, port=port, cycle="10ms", sample="50ms")
    ctl = softplc("run", "--sim", str(plant), cwd=tmp_path, log=tmp_path / "run.log")
    try:
        wait_until(lambda: os.path.exists(tmp_path / "feed.sock") or ctl.poll() is not None,
                   30.0, "the feed socket")
        assert ctl.poll() is None, (tmp_path / "run.log").read_text()
        with ServerThread(load_plant(str(plant))) as srv:
            first_frame(srv)
            delay, bad = asyncio.run(_watch_a_stall(
                srv.url, lambda: ctl.send_signal(signal.SIGSTOP),
                lambda: ctl.send_signal(signal.SIGCONT)))
    finally:
        end(ctl)
    assert delay <= BOUND_S + SLACK_S, delay
    sys.stderr.write(f"SIGSTOP: values BadOutOfService {delay * 1000:.0f} ms after the last "
                     "frame\n")


def test_a_scan_stuck_with_its_outputs_off_turns_every_value_bad(tmp_path: Path) -> None:
    """A scan stuck in a driver call (a hung bus): the watchdog thread switches the
    outputs off at once, the scan ends only 4 s later (then a fault)."""
    pdef = load_plant(str(write_plant(tmp_path, port=free_port(), watchdog="200ms")))
    drv = RecordingDriver("io", {"on_fault": "stop"})
    with serving(pdef, Plant(pdef, drivers={"io": drv})):
        with ServerThread(pdef) as srv:
            first_frame(srv)

            def stall() -> None:
                drv.block_s = 4.0
            delay, bad = asyncio.run(_watch_a_stall(srv.url, stall, lambda: None))

            async def state() -> str:
                async with Client(srv.url) as c:
                    return str(await c.get_node("ns=2;s=controller.state").read_value())
            assert asyncio.run(state()) == "fault"
    assert drv.wrote_safe.is_set()  # the watchdog switched the outputs off meanwhile
    assert delay <= BOUND_S + SLACK_S, delay
    sys.stderr.write(f"stuck scan: values BadOutOfService {delay * 1000:.0f} ms after the last "
                     "frame\n")


def test_a_busy_server_event_loop_turns_no_value_bad(
        tmp_path: Path, caplog: pytest.LogCaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The OPC UA server's own event loop blocked for longer than the bound (a long
    callback, a slow client's request) while the controller runs: no value turns bad,
    since the controller kept writing (its own stamp in the shared image says so); only
    the controller stopping writing makes values stale. The feed's buffers are made
    small (a large plant's frames fill the real ones as fast): frames over the socket
    would pile up and the controller would drop the server, every value then
    BadNoCommunication."""
    monkeypatch.setattr(feed_module, "OUT_MAX", 8192)
    pdef = load_plant(str(write_plant(tmp_path, port=free_port(), sample="10ms")))
    with serving(pdef) as (_d, feed), ServerThread(pdef) as srv:
        ps = srv.ps
        assert ps is not None and srv._loop is not None
        wait_until(lambda: ps.connected.is_set() and ps.state.scan > 0
                   and len(ps.state.values) == len(ps.space.nodes), 20.0, "values")
        for c in feed._clients:
            c.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        caplog.set_level(logging.INFO)
        blocked, woke = threading.Event(), threading.Event()

        def block() -> None:
            blocked.set()
            time.sleep(2 * BOUND_S + 1.0)  # the loop does nothing else meanwhile
            woke.set()
        srv._loop.call_soon_threadsafe(block)
        assert blocked.wait(10.0) and woke.wait(30.0)
        after = ps.state.scan
        # the loop runs again: let it serve many samples (and its stale checks) after
        wait_until(lambda: ps.state.scan >= after + 50, 20.0, "frames after the block")
        assert not ps.stale and ps.connected.is_set()
        assert feed.dropped == 0
        said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
        assert not [m for m in said if "BadOutOfService" in m or "lost" in m], said
