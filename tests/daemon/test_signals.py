"""Signals of a real ``softplc run``: SIGHUP, SIGINT, SIGTERM and SIGQUIT are each an
orderly stop (every output off on the Modbus RTU module across a pty, retained data saved,
one line naming the signal, exit status 0); SIGHUP stays ignored under ``nohup``; SIGPIPE
(a console client or a trace reader gone) harms nothing."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from runtime.controller.retain import RetainStore
from tests.daemon.daemonkit import wait_until
from tests.daemon.test_daemon_process import ROOT, Console, coils, plant, start, stop
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

#: Modbus function codes that write coils
WRITE_COILS = (5, 15)


@pytest.fixture
def line() -> Iterator[tuple[PtyBridge, ModbusPeer]]:
    with PtyBridge() as bridge, ModbusPeer(bridge.peer_port, (1,)) as peer:
        yield bridge, peer


def counted(con: Console) -> int:
    """The chart's retained scan counter m.sN, read over the console."""
    m = re.search(r"m\.sN=(\d+)", con.cmd("get m.sN"))
    return int(m.group(1)) if m else -1


def scan_count(con: Console) -> int:
    m = re.search(r"scans (\d+)", con.cmd("status"))
    assert m is not None
    return int(m.group(1))


@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT, signal.SIGTERM,
                                 signal.SIGQUIT], ids=lambda s: signal.Signals(s).name)
def test_each_stop_signal_is_an_orderly_safe_stop(tmp_path: Path,
                                                  line: tuple[PtyBridge, ModbusPeer],
                                                  sig: int) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])  # iGo: the chart switches both outputs on
    sock = tmp_path / "console.sock"
    # retained data is saved only at the stop: a value in the file proves the stop saved it
    proc = start(plant(tmp_path, bridge.driver_port, tolerant=True,
                       retain_interval="3600s"), {})
    try:
        wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
        con = Console(sock)
        wait_until(lambda: counted(con) > 5, 20, "the chart counting")
        seen = counted(con)
        con.close()
        writes_before = len(peer.served)
    finally:
        code, err = stop(proc, sig)
    name = signal.Signals(sig).name
    assert code == 0, err
    assert len([ln for ln in err.splitlines() if f"stopping: {name}" in ln]) == 1, err
    assert coils(peer) == [0, 0], "an output stayed on after the stop"
    last_write = [r for r in peer.served[writes_before:] if r[1] in WRITE_COILS][-1]
    assert last_write[2] == 0  # the last coil write covered Q0.. and left them off
    saved = RetainStore(str(tmp_path / "var" / "retain.json")).load()
    assert saved.source is not None, "retained data not saved at the stop"
    assert saved.data["m"]["sN"] >= seen
    assert "Traceback" not in err


def test_sighup_stays_ignored_under_nohup(tmp_path: Path,
                                          line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])
    sock = tmp_path / "console.sock"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("JOURNAL_STREAM", None)
    path = plant(tmp_path, bridge.driver_port, tolerant=True)
    proc = subprocess.Popen(["nohup", sys.executable, "-m",
                             "runtime.cli", "run", str(path)], cwd=str(tmp_path), env=env,
                            text=True, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
        con = Console(sock)
        proc.send_signal(signal.SIGHUP)
        # the console answers after the signal was delivered: the process lives on
        assert "state running" in con.cmd("status")
        con.close()
        assert proc.poll() is None
        assert coils(peer) == [1, 1]
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert "stopping: SIGTERM" in err and "SIGHUP" not in err
    assert coils(peer) == [0, 0]


def test_sigpipe_from_gone_clients_and_trace_readers_harms_nothing(
        tmp_path: Path, line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])
    sock = tmp_path / "console.sock"
    fifo = tmp_path / "trace.fifo"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)  # so the daemon's open returns
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("JOURNAL_STREAM", None)
    proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run",
                             str(plant(tmp_path, bridge.driver_port, tolerant=True)), "--trace",
                             str(fifo)],
                            cwd=str(tmp_path), env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
        # the trace reader reads a little and goes away: the next write gets EPIPE
        got = b""
        end = time.monotonic() + 20
        while b"\n" not in got and time.monotonic() < end:
            try:
                got += os.read(reader, 4096)
            except BlockingIOError:
                time.sleep(0.01)
        assert b'"cycle"' in got
        os.close(reader)
        con = Console(sock)  # the operator's session, opened before the others come
        # console clients that send a lot and hang up without reading the replies
        for _ in range(20):
            with socket.socket(socket.AF_UNIX) as c:
                c.connect(str(sock))
                c.sendall(b"help\n" * 50)
        scans = scan_count(con)  # some cycles to write into the closed pipe and sockets
        wait_until(lambda: scan_count(con) > scans + 25, 20, "cycles after the hang-ups")
        assert proc.poll() is None, "the controller died"
        assert "state running" in con.cmd("status")
        con.close()
        assert coils(peer) == [1, 1]
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert coils(peer) == [0, 0]
    assert "Traceback" not in err, err
    assert len(re.findall(r"trace.*(Broken pipe|EPIPE)", err)) == 1, err


def test_a_stop_while_the_module_is_faulted_still_switches_its_outputs_off(
        tmp_path: Path, line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])
    sock = tmp_path / "console.sock"
    proc = start(plant(tmp_path, bridge.driver_port, tolerant=True), {})
    try:
        wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
        bridge.cut = True  # the cable is pulled: the unit faults, its relays stay on
        con = Console(sock)
        wait_until(lambda: "state fault" in con.cmd("status"), 20, "the fault")
        con.close()
        # the attack: out long enough for the reconnect back-off to grow (retries 0.1,
        # 0.3, 0.7, 1.5, 3.1 s after the fault), then back between two retries
        time.sleep(2.0)
        bridge.cut = False  # plugged in again, and the controller is stopped at once
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert coils(peer) == [0, 0], err


def test_a_stop_with_the_module_unreachable_says_its_outputs_may_be_on(
        tmp_path: Path, line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])
    sock = tmp_path / "console.sock"
    proc = start(plant(tmp_path, bridge.driver_port, tolerant=True), {})
    try:
        wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
        bridge.cut = True
        con = Console(sock)
        wait_until(lambda: "state fault" in con.cmd("status"), 20, "the fault")
        con.close()
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert coils(peer) == [1, 1]  # nothing could reach the module: its relays stay on
    assert len(re.findall(r"driver mb: unit 1 did not confirm the safe state before the "
                          r"port closed: its outputs may still be on", err)) == 1, err
