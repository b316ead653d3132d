"""Online change of ``softplc run`` (a child process) on a real Modbus RTU peer over a pty,
through ``softplc reload`` (the CLI, as systemd's ExecReload runs it): the coil writes the
peer records show no output change at the swap that the new program does not make, the
count goes on, a refused change exits 1 with its reason and changes nothing, no console
exits 2. The console socket is neither trusted nor PIN-protected: only this process's own
user may reload there (docs/online-change.md, "Applying a change to a running
controller")."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.daemon.daemonkit import wait_until
from tests.daemon.test_daemon_process import ROOT, Console, start, stop
from tests.drivers.modbus_peer import ModbusPeer
from tests.drivers.pty_bridge import PtyBridge

STEADY = """\
grafcet: Steady
inputs: [iGo]
outputs: [oRun, oLamp]
memory:
  sN: {init: 0, retain: true}
  sMaint: false
steps:
  gsIdle: {initial: true}
  gsRun: {actions: [oRun, "N sN := sN + 1"]}
transitions:
  - {from: gsIdle, to: gsRun, when: iGo}
  - {from: gsRun, to: gsIdle, when: "iGo'"}
post:
  - oLamp := gsRun.X
"""

#: a new step on the inactive branch (gsIdle -> gsMaint): the outputs stay as they are
NEW_STEP = STEADY.replace(
    "  gsRun: {actions",
    "  gsMaint: {actions: [oLamp]}\n  gsRun: {actions").replace(
    "transitions:\n",
    "transitions:\n  - {from: gsIdle, to: gsMaint, when: sMaint}\n"
    "  - {from: gsMaint, to: gsIdle, when: \"sMaint'\"}\n")
#: ...then the lamp goes off: the one output change the new program makes at the swap
LAMP_OFF = NEW_STEP.replace("oLamp := gsRun.X", "oLamp := gsIdle.X")


class RecordingPeer(ModbusPeer):
    """The Modbus unit, recording every coil write it is sent: (time, [Q0, Q1])."""

    def __init__(self, port: str) -> None:
        super().__init__(port, (1,))
        self.writes: list[tuple[float, list[int]]] = []
        self.lock = threading.Lock()

    async def _action(self, unit: int, function_code: int, start_address: int,
                      address: int, count: int, registers: list[int],
                      set_values: Any) -> Any:
        if function_code in (5, 15) and set_values is not None and address == 0:
            with self.lock:
                self.writes.append((time.monotonic(), [int(v) for v in set_values][:2]))
        return await super()._action(unit, function_code, start_address, address, count,
                                     registers, set_values)

    def coils(self) -> list[list[int]]:
        with self.lock:
            return [v for _, v in self.writes]


@pytest.fixture
def line() -> Iterator[tuple[PtyBridge, RecordingPeer]]:
    with PtyBridge() as bridge:
        peer = RecordingPeer(bridge.peer_port)
        peer.start()
        try:
            yield bridge, peer
        finally:
            peer.stop()


def plant(tmp: Path, port: str) -> Path:
    (tmp / "steady.yaml").write_text(STEADY, encoding="utf-8")
    path = tmp / "plant.yaml"
    path.write_text(f"""\
plc:
  cycle: 20ms
  watchdog: 500ms
  retain: {tmp}/var/retain.json
drivers:
  mb: {{type: modbus_rtu, port: {port}, baudrate: 115200, unit: 1, timeout: 300ms,
        retries: 1}}
instances:
  m:
    grafcet: steady.yaml
    inputs: {{iGo: mb.I0}}
    outputs: {{oRun: mb.Q0, oLamp: mb.Q1}}
monitor:
  socket: {{path: {tmp}/console.sock}}
""", encoding="utf-8")
    return path


def softplc_reload(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "runtime.cli", "reload", *args],
                          capture_output=True, text=True, timeout=120, env=env)


def sn(con: Console) -> int:
    return int(con.json("get m.sN")["values"]["m.sN"])


def test_reload_a_running_controller_with_a_modbus_peer(
        tmp_path: Path, line: tuple[PtyBridge, RecordingPeer]) -> None:
    bridge, peer = line
    path = plant(tmp_path, bridge.driver_port)
    peer.set(1, 2, 0, [1])  # iGo on: gsRun, both coils on
    proc = start(path, {})
    sock = tmp_path / "console.sock"
    con = None
    try:
        con = Console(sock)
        wait_until(lambda: [1, 1] in peer.coils(), 20.0, "both coils on")
        # an untrusted socket without a PIN refuses set...
        assert "changing commands are disabled" in con.cmd("set m.sMaint 1")
        n0 = sn(con)
        (tmp_path / "steady.yaml").write_text(NEW_STEP, encoding="utf-8")
        # ...but this process's own user may reload (ExecReload runs as the service's)
        r = softplc_reload(str(sock))
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith("reload applied in "), r.stdout
        assert "gsMaint" in r.stdout
        wait_until(lambda: sn(con) >= n0 + 20, 20.0, "the count to go on")
        mark = len(peer.coils())
        (tmp_path / "steady.yaml").write_text(LAMP_OFF, encoding="utf-8")
        r = softplc_reload(str(sock))
        assert r.returncode == 0, r.stderr
        wait_until(lambda: [1, 0] in peer.coils()[mark:], 20.0, "the lamp off")
        n1 = sn(con)
        wait_until(lambda: sn(con) >= n1 + 20, 20.0, "the count to go on")
        # refused: the active step renamed without renamed_from: is removed
        (tmp_path / "steady.yaml").write_text(LAMP_OFF.replace("gsRun", "gsGo"),
                                              encoding="utf-8")
        r = softplc_reload(str(sock))
        assert r.returncode == 1, (r.stdout, r.stderr)
        assert ("softplc reload: refused: m: step gsRun removed while it is active "
                "(--restart m restarts that instance)") in r.stderr, r.stderr
        status = con.json("status")
        assert status["state"] == "running" and status["steps"] == {"m": ["gsRun"]}
        assert status["reload"]["summary"].startswith("1 change")
        n2 = sn(con)
        wait_until(lambda: sn(con) >= n2 + 10, 20.0, "the count to go on")
        assert softplc_reload(str(tmp_path / "nope.sock")).returncode == 2
    finally:
        if con is not None:
            con.close()
        code, err = stop(proc)
    assert code == 0, err
    coils = peer.coils()
    first = coils.index([1, 1])
    # the last writes are the orderly stop's (every output off): before them, oRun was
    # never dropped and the lamp changed once, 1 -> 0, at the second swap
    end = len(coils) - next(i for i, v in enumerate(reversed(coils)) if v != [0, 0])
    during = coils[first:end]
    assert all(q0 == 1 for q0, _ in during), during
    lamp = [q1 for _, q1 in during]
    assert lamp == sorted(lamp, reverse=True) and lamp[-1] == 0, lamp
    assert "reload applied" in err and "sha256" in err, err[-2000:]
