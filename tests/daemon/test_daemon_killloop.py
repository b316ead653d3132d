"""kill -9 at random moments, many times: the retained counter restored afterwards is
never corrupt and never older than one retain interval (plus the time the write takes).

The daemon runs a chart that counts every scan into retained memory and saves every
50 ms; the test reads the live counter over the console just before each kill, then
loads the retain file as the next start will (and the next start must go on from it).
200 kills by default (SOFTPLC_KILL_LOOPS), about three minutes: marked slow."""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from runtime.controller.retain import RetainStore

ROOT = Path(__file__).resolve().parents[2]
CYCLE_MS = 10
INTERVAL_MS = 50
#: time for a save to reach the disk after it was handed over, generous (ms)
WRITE_MS = 200

COUNTER = """\
grafcet: Counter
inputs: [iUnused]
outputs: [oLamp]
memory:
  sN: {init: 0, retain: true}
steps:
  gsCount: {initial: true, actions: [oLamp, "N sN := sN + 1"]}
transitions: []
"""


def get_counter(sock_path: str, timeout: float = 20.0) -> int:
    end = time.monotonic() + timeout
    while True:
        try:
            with socket.socket(socket.AF_UNIX) as s:
                s.connect(sock_path)
                s.settimeout(5)
                s.sendall(b"get m.sN\n")
                out = b""
                while not out.endswith(b"ok\r\n"):
                    chunk = s.recv(4096)
                    if not chunk:
                        raise ConnectionError("closed")
                    out += chunk
            return int(out.decode().split("m.sN=")[1].split()[0])
        except (FileNotFoundError, ConnectionError, OSError):
            if time.monotonic() > end:
                raise
            time.sleep(0.02)


@pytest.mark.slow
def test_kill_9_never_loses_more_than_one_interval(tmp_path: Path) -> None:
    loops = int(os.environ.get("SOFTPLC_KILL_LOOPS", "200"))
    (tmp_path / "counter.yaml").write_text(COUNTER, encoding="utf-8")
    retain = tmp_path / "var" / "retain.json"
    sock = tmp_path / "console.sock"
    plant = tmp_path / "plant.yaml"
    plant.write_text(f"""\
plc: {{cycle: {CYCLE_MS}ms, watchdog: 200ms, retain: {retain}, retain_interval: {INTERVAL_MS}ms}}
drivers: {{sim: {{type: sim}}}}
instances:
  m:
    grafcet: counter.yaml
    inputs: {{iUnused: sim.I0}}
    outputs: {{oLamp: sim.Q0}}
monitor:
  socket: {{path: {sock}, trusted: true}}
""", encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    rng = random.Random(2026)
    previous = 0
    fallbacks = 0
    worst_age_ms = 0.0
    for i in range(loops):
        if sock.exists():
            sock.unlink()
        proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", str(plant)],
                                env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        try:
            first = get_counter(str(sock))
            assert first >= previous, f"kill {i}: restarted at {first} < restored {previous}"
            time.sleep(rng.uniform(0.0, 0.4))
            live = get_counter(str(sock))
            t_kill = time.time()
            proc.send_signal(signal.SIGKILL)
        finally:
            proc.kill()
            proc.communicate()
        loaded = RetainStore(str(retain)).load()
        bad = [p for p in loaded.problems if "restored generation" not in p]
        assert not bad, f"kill {i}: {bad}"
        assert loaded.source is not None, f"kill {i}: nothing restorable"
        fallbacks += loaded.source != str(retain)
        restored = int(loaded.data["m"]["sN"])
        assert loaded.saved_at is not None
        age_ms = (t_kill - loaded.saved_at) * 1000
        worst_age_ms = max(worst_age_ms, age_ms)
        # never older than one interval (+ the write's own time), never from the future
        assert age_ms <= INTERVAL_MS + WRITE_MS, f"kill {i}: saved {age_ms:.0f} ms before"
        assert restored >= live - (INTERVAL_MS + WRITE_MS) // CYCLE_MS, \
            f"kill {i}: restored {restored}, live {live}"
        assert restored <= live + (WRITE_MS // CYCLE_MS)
        previous = restored
    sys.stderr.write(f"{loops} kills: {fallbacks} restored from .prev/.tmp, worst age "
                     f"{worst_age_ms:.0f} ms, final count {previous}\n")
