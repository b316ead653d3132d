"""kill -9 at random moments, many times: the retained counter restored afterwards is
never corrupt and never more than one retain interval (plus the time of a write) of counts
behind the live counter.

The daemon runs a chart that counts every scan into retained memory and saves every
50 ms; the test reads the live counter over the console just before each kill, then
loads the retain file as the next start will (and the next start must go on from it).
200 kills by default (SOFTPLC_KILL_LOOPS), about three minutes: marked slow.

The bound is on the data, in counts, not on the file's age: on a loaded machine a freeze
longer than the watchdog faults the controller (charts stopped, recorded, so the next start
comes up in fault): nothing changes, nothing is saved, nothing is lost, and the file only
gets older (issue 25 saw "saved 1442 ms before"). The test acknowledges such a fault so
that the next kills test saves again, and counts them (docs/daemon.md, "Retained memory").
"""

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


def request(sock_path: str, line: bytes, timeout: float = 20.0) -> str:
    """One console request, retried until the console answers."""
    end = time.monotonic() + timeout
    while True:
        try:
            with socket.socket(socket.AF_UNIX) as s:
                s.connect(sock_path)
                s.settimeout(5)
                s.sendall(line + b"\n")
                out = b""
                while not (out.endswith(b"ok\r\n") or
                           b"error" in out and out.endswith(b"\r\n")):
                    chunk = s.recv(4096)
                    if not chunk:
                        raise ConnectionError("closed")
                    out += chunk
            return out.decode()
        except (FileNotFoundError, ConnectionError, OSError):
            if time.monotonic() > end:
                raise
            time.sleep(0.02)


def get_counter(sock_path: str, timeout: float = 20.0) -> int:
    return int(request(sock_path, b"get m.sN", timeout).split("m.sN=")[1].split()[0])


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
    faults = 0
    worst_age_ms = 0.0
    worst_lost = 0
    for i in range(loops):
        if sock.exists():
            sock.unlink()
        proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", str(plant)],
                                env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        try:
            first = get_counter(str(sock))
            assert first >= previous, f"kill {i}: restarted at {first} < restored {previous}"
            if "state fault" in request(str(sock), b"status"):  # a freeze on a busy machine
                faults += 1
                request(str(sock), b"ack")
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
        worst_lost = max(worst_lost, live - restored)
        # never more than one interval (+ the write's own time) of counts lost, never
        # from the future
        assert restored >= live - (INTERVAL_MS + WRITE_MS) // CYCLE_MS, \
            f"kill {i}: restored {restored}, live {live} (saved {age_ms:.0f} ms before)"
        assert restored <= live + (WRITE_MS // CYCLE_MS)
        previous = restored
    sys.stderr.write(f"{loops} kills: {fallbacks} restored from .prev/.tmp, worst loss "
                     f"{worst_lost} counts ({worst_lost * CYCLE_MS} ms of scans), worst age "
                     f"{worst_age_ms:.0f} ms, {faults} freeze faults acknowledged, final "
                     f"count {previous}\n")


def test_after_a_freeze_fault_the_file_ages_and_nothing_is_lost(tmp_path: Path) -> None:
    """What made the old bound (the file's age) fail on a busy machine (issue 25: "saved
    1442 ms before"): a freeze longer than the watchdog faults the controller and records
    it; the next start comes up in fault, its charts stopped: the counter stands still,
    nothing is saved, the file gets older, and a kill loses nothing."""
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

    def start() -> subprocess.Popen[str]:
        return subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", str(plant)],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True)
    proc = start()
    try:
        get_counter(str(sock))
        proc.send_signal(signal.SIGSTOP)  # frozen for longer than the watchdog
        time.sleep(0.6)
        proc.send_signal(signal.SIGCONT)
        end = time.monotonic() + 20
        while "state fault" not in request(str(sock), b"status"):
            assert time.monotonic() < end, "no freeze fault"
            time.sleep(0.05)
    finally:
        proc.kill()
        proc.communicate()
    proc = start()
    try:
        assert "state fault" in request(str(sock), b"status")  # carried over the restart
        before = get_counter(str(sock))
        time.sleep(1.0)
        live = get_counter(str(sock))
        t_kill = time.time()
    finally:
        proc.kill()
        proc.communicate()
    loaded = RetainStore(str(retain)).load()
    assert loaded.saved_at is not None
    assert live == before == int(loaded.data["m"]["sN"])  # nothing changed, nothing lost
    assert (t_kill - loaded.saved_at) * 1000 > INTERVAL_MS + WRITE_MS  # the old bound
