"""``softplc run`` as a child process, with real peers: a pymodbus RTU server on a pty pair
as the I/O module (so the outputs the drivers sent are read back from the module), an
AF_UNIX datagram socket as systemd's notify socket, the console on a Unix socket.
Covers sd_notify (READY after the first scan, WATCHDOG while healthy, STATUS, STOPPING),
the watchdog trip of a hung scan, SIGTERM/SIGINT in the middle of scans, and the end of
``--for``: every time, the module's outputs end off."""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.daemon.daemonkit import wait_until
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

ROOT = Path(__file__).resolve().parents[2]

BUSY = """\
grafcet: Busy
inputs: [iGo]
outputs: [oRun, oLamp]
memory:
  sN: {init: 0, retain: true}
  sLoops: LOOPS
  sAcc: 0
steps:
  gsIdle: {initial: true}
  gsRun: {actions: [oRun, "N sN := sN + 1"]}
transitions:
  - {from: gsIdle, to: gsRun, when: iGo}
  - {from: gsRun, to: gsIdle, when: "iGo'"}
post:
  - oLamp := gsRun.X
  - |
    FOR tI := 1 TO sLoops DO      // busy work: makes a scan as long as a test needs
      sAcc := sAcc + 1
    END_FOR
"""


def plant(tmp: Path, port: str, cycle: str = "20ms", loops: int = 0,
          watchdog: str = "100ms", retain_interval: str = "1s",
          reply_timeout: str = "50ms", tolerant: bool = False) -> Path:
    """The BUSY chart on a Modbus RTU unit at ``port``. ``tolerant``: a watchdog and a
    reply timeout that a loaded 2-core test machine holds, for tests that are not about
    the timing of either (signals, freezes)."""
    if tolerant:
        watchdog, reply_timeout = "500ms", "300ms"
    (tmp / "busy.yaml").write_text(BUSY.replace("LOOPS", str(loops)), encoding="utf-8")
    path = tmp / "plant.yaml"
    path.write_text(f"""\
plc:
  cycle: {cycle}
  watchdog: {watchdog}
  retain: {tmp}/var/retain.json
  retain_interval: {retain_interval}
drivers:
  mb: {{type: modbus_rtu, port: {port}, baudrate: 115200, unit: 1, timeout: {reply_timeout},
        retries: 1}}
instances:
  m:
    grafcet: busy.yaml
    inputs: {{iGo: mb.I0}}
    outputs: {{oRun: mb.Q0, oLamp: mb.Q1}}
monitor:
  socket: {{path: {tmp}/console.sock, trusted: true}}
""", encoding="utf-8")
    return path


@pytest.fixture
def line() -> Iterator[tuple[PtyBridge, ModbusPeer]]:
    with PtyBridge() as bridge, ModbusPeer(bridge.peer_port, (1,)) as peer:
        yield bridge, peer


class NotifySocket:
    """systemd's side of sd_notify: a datagram socket collecting the daemon's messages."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(self.path)
        self.sock.settimeout(0.05)
        self.messages: list[tuple[float, str]] = []

    def collect(self, seconds: float) -> list[str]:
        end = time.monotonic() + seconds
        got = []
        while time.monotonic() < end:
            try:
                data = self.sock.recv(4096).decode()
            except TimeoutError:
                continue
            self.messages.append((time.monotonic(), data))
            got.append(data)
        return got

    def drain(self) -> list[str]:
        """Every message already queued (sent before now)."""
        got = []
        self.sock.setblocking(False)
        try:
            while True:
                data = self.sock.recv(4096).decode()
                self.messages.append((time.monotonic(), data))
                got.append(data)
        except BlockingIOError:
            pass
        finally:
            self.sock.settimeout(0.05)
        return got

    def wait_for(self, prefix: str, timeout: float = 20.0) -> str:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for msg in self.collect(0.05):
                if msg.startswith(prefix):
                    return msg
        raise AssertionError(f"no {prefix} from the daemon; got {self.messages[-5:]}")

    def close(self) -> None:
        self.sock.close()


def start(plant_path: Path, env_extra: dict[str, str]) -> subprocess.Popen[str]:
    env = {**os.environ, **env_extra, "PYTHONPATH": str(ROOT)}
    env.pop("JOURNAL_STREAM", None)
    return subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", str(plant_path)],
                            cwd=str(plant_path.parent), env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def console(path: Path, command: str) -> str:
    with socket.socket(socket.AF_UNIX) as s:
        s.connect(str(path))
        s.settimeout(10)
        s.sendall(command.encode() + b"\n")
        out = b""
        while not (out.endswith(b"ok\r\n") or b"error" in out):
            chunk = s.recv(4096)
            if not chunk:
                break
            out += chunk
    return out.decode()


class Console:
    """One console session on the Unix socket, kept for a whole test as an operator's
    terminal is (a connection per request would run into the bound on sessions)."""

    def __init__(self, path: Path, timeout: float = 20.0) -> None:
        self.sock = socket.socket(socket.AF_UNIX)
        end = time.monotonic() + timeout  # the controller may still be starting
        while True:
            try:
                self.sock.connect(str(path))
                break
            except (FileNotFoundError, ConnectionRefusedError):
                if time.monotonic() > end:
                    raise
                time.sleep(0.02)
        self.sock.settimeout(timeout)
        self._buf = b""

    def _line(self) -> str:
        while b"\n" not in self._buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError(f"the console closed the session: {self._buf!r}")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return line.decode().rstrip("\r")

    def cmd(self, command: str) -> str:
        """The reply to ``command``, up to its final line (``ok``, ``error ...`` or a
        JSON object)."""
        self.sock.sendall(command.encode() + b"\n")
        lines = []
        while True:
            lines.append(self._line())
            if lines[-1] == "ok" or lines[-1].startswith(("error", "{")):
                return "\r\n".join(lines) + "\r\n"

    def json(self, command: str) -> dict[str, Any]:
        """``command`` answered as JSON (the session is switched to JSON on first use)."""
        if not getattr(self, "_json", False):
            self.cmd("json on")
            self._json = True
        reply: dict[str, Any] = json.loads(self.cmd(command).splitlines()[-1])
        return reply

    def close(self) -> None:
        self.sock.close()


def coils(peer: ModbusPeer) -> list[int]:
    return peer.get(1, 1, 0, 2)


def stop(proc: subprocess.Popen[str], sig: int = signal.SIGTERM) -> tuple[int, str]:
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return proc.returncode, err


def test_notify_watchdog_trip_ack_and_sigterm(tmp_path: Path,
                                              line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, peer = line
    peer.set(1, 1, 0, [1, 1])  # the module's relays were left on by someone
    notify = NotifySocket(tmp_path / "notify.sock")
    # tolerant: the hung scan below trips a 500 ms watchdog as surely, and a pause of this
    # process (the unit's peer) or of the machine no longer faults it first
    proc = start(plant(tmp_path, bridge.driver_port, tolerant=True),
                 {"NOTIFY_SOCKET": notify.path, "WATCHDOG_USEC": "200000"})
    try:
        ready = notify.wait_for("READY=1")
        assert "STATUS=running" in ready
        assert coils(peer) == [0, 0], "outputs not written off before the first scan"
        peer.set(1, 2, 0, [1])  # iGo
        wait_until(lambda: coils(peer) == [1, 1], 10, "outputs on")
        pings = [m for m in notify.collect(1.0) if m == "WATCHDOG=1"]
        assert 5 <= len(pings) <= 20  # every 100 ms (half of WatchdogSec)

        # a scan that takes seconds: the watchdog thread puts the outputs off meanwhile,
        # and systemd's watchdog is no longer fed while the scan thread is stuck
        assert "ok" in console(tmp_path / "console.sock", "set m.sLoops 40000000")
        wait_until(lambda: coils(peer) == [0, 0], 10, "outputs off during the hung scan")
        t_off = time.monotonic()
        notify.drain()  # pings sent before the scan hung
        during = notify.collect(0.8)
        assert "WATCHDOG=1" not in during
        # the scan ends; the loop goes on in fault (pings again), outputs stay off
        notify.wait_for("WATCHDOG=1", timeout=60)
        status = console(tmp_path / "console.sock", "status")
        assert "state fault (watchdog: a scan has been running for" in status
        assert time.monotonic() - t_off > 0.8
        assert coils(peer) == [0, 0]
        refused = console(tmp_path / "console.sock", "get m.sAcc")
        assert "m.sAcc=" in refused

        assert "ok" in console(tmp_path / "console.sock", "ack")
        # restarted from the initial situation: sLoops is 0 again, iGo still 1
        wait_until(lambda: coils(peer) == [1, 1], 10, "outputs on after ack")
    finally:
        code, err = stop(proc)
        notify.collect(0.3)
        notify.close()
    assert code == 0, err
    assert coils(peer) == [0, 0]
    last = [m for _, m in notify.messages][-1]
    assert last.startswith("STOPPING=1"), notify.messages[-3:]
    assert "stopping: SIGTERM" in err


def busy_loops_for(con: Console, scan_ms: float) -> int:
    """The chart's busy-loop count that makes a scan last about ``scan_ms`` on this
    machine now: measured on the running controller, not assumed."""
    loops = 20_000
    for _ in range(4):  # each round rescales from the scan time it measured
        assert "ok" in con.cmd(f"set m.sLoops {loops}")
        before = con.json("stats")["stats"]["cycles"]
        wait_until(lambda: con.json("stats")["stats"]["cycles"] > before + 3,  # noqa: B023
                   20, "cycles with the new loop count")
        last_ms = con.json("stats")["stats"]["scan_us"]["last"] / 1000
        loops = max(1000, int(loops * scan_ms / max(last_ms, 0.1)))
    return loops


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_in_the_middle_of_scans_ends_with_outputs_off(
        tmp_path: Path, line: tuple[PtyBridge, ModbusPeer], sig: int) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])
    sock = tmp_path / "console.sock"
    # each scan spends about 60 % of its 50 ms cycle in the chart's busy loop, sized by
    # time on the running controller; a generous watchdog, as load stretches the scans
    path = plant(tmp_path, bridge.driver_port, cycle="50ms", watchdog="2s")
    rng = random.Random(sig)
    loops = 0
    for _ in range(3):
        notify = NotifySocket(tmp_path / f"n{rng.random()}.sock")
        proc = start(path, {"NOTIFY_SOCKET": notify.path})
        failed: AssertionError | None = None
        try:
            notify.wait_for("READY=1")
            wait_until(lambda: coils(peer) == [1, 1], 20, "outputs on")
            con = Console(sock)
            if not loops:
                loops = busy_loops_for(con, 30.0)
            else:
                assert "ok" in con.cmd(f"set m.sLoops {loops}")
            con.close()
            time.sleep(rng.uniform(0.0, 0.3))  # a random moment in the scans
        except AssertionError as exc:  # said with the controller's own log
            failed = exc
        finally:
            code, err = stop(proc, sig)
            notify.close()
        if failed is not None:
            raise AssertionError(f"{failed}\n--- the controller's log:\n{err[-4000:]}")
        assert code == 0, err
        assert f"stopping: {signal.Signals(sig).name}" in err
        assert coils(peer) == [0, 0], err


def test_end_of_for_is_an_orderly_stop(tmp_path: Path,
                                       line: tuple[PtyBridge, ModbusPeer]) -> None:
    bridge, peer = line
    peer.set(1, 2, 0, [1])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    # not about the timing of the watchdog or of the unit's replies: the tolerant ones (at a
    # load of 10-18 on 2 cores the 100 ms watchdog or the 50 ms reply timeout faulted it)
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "run",
                           str(plant(tmp_path, bridge.driver_port, tolerant=True)), "--for",
                           "1500ms"], env=env, text=True, capture_output=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "stopping: end of --for" in proc.stderr
    assert coils(peer) == [0, 0]
    # the chart did run (sN counts the scans of gsRun and is retained)
    from runtime.controller.retain import RetainStore

    assert RetainStore(str(tmp_path / "var" / "retain.json")).load().data["m"]["sN"] > 10
