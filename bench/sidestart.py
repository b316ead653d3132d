"""Benchmark: what starting a side process (``softplc opcua``, ``mqtt``, ``web``) costs the
scan, to choose the default ``plc: watchdog`` from (docs/daemon.md). Not a test: prints a
table.

The controller runs in this process as in bench/opcua.py (the same Daemon, Scheduler,
feed server and generated plant cycle as ``softplc run --sim``), with ``--testers`` drawer
testers whose drawers move, at a 10 ms cycle and a 6 s watchdog (the longest: a late
wake-up is measured, not turned into a fault). The plant has an ``opcua:``, an ``mqtt:``
(Debian's mosquitto on a loopback port, started here) and a ``web:`` section. For each
side process, ``--repeat`` times, two windows one after the other:

- ``start``: ``softplc SIDE PLANT`` is started at the window's start, as its systemd unit
  or a person by hand starts it (it imports its libraries, reads the plant, connects to the
  feed, gets the schema and serves: the OPC UA address space, the MQTT births, the page);
  the window lasts until ``--window`` seconds after it says it serves; it is stopped then;
- ``control``: as long, nothing starting (the machine's own load, and ``--load`` busy
  processes).

Per window: the scan's wake-up lateness (p99, max) and scan time (max), overruns, and how
long the side process took to say it serves (its log line). The watchdog trips on a scan
longer than it, or a wake-up later than it (a freeze): the figure to hold against a
watchdog is the larger of the two maxima, the last columns.

``--priority fifo`` runs the scan at SCHED_FIFO 50 (the default wherever permitted: the
installed service, root); ``normal`` at normal priority (``plc: realtime: false``, a user's
controller started by hand where SCHED_FIFO is not permitted).

    python -m bench.sidestart [--testers 2] [--repeat 3] [--window 5] [--load 2]
                              [--priority fifo,normal] [--sides opcua,mqtt,web]
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from bench.jitter import plant_file
from bench.opcua import end_process, out, start_daemon, stop_daemon
from runtime.controller.daemon import Daemon

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
#: what each side process logs once it serves
SERVING = {"opcua": re.compile(r"OPC UA server on "),
           "mqtt": re.compile(r"mqtt: connected to "),
           "web": re.compile(r"web: the page of \S+ is at ")}
#: the longest a side process may take to say it serves, s (a window ends then)
MAX_WINDOW_S = 180.0
#: candidate watchdogs held against the figures, ms
CANDIDATES = (100, 250, 500, 1000)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def side_plant(directory: str, testers: int, fifo: bool, broker: int) -> str:
    """bench/jitter.py's plant of ``testers`` testers at 10 ms with a 6 s watchdog and the
    three side sections, its feed in ``directory``."""
    path = plant_file(directory, testers, 10, fifo)
    with open(path, encoding="utf-8") as f:
        text = f.read()
    text = re.sub(r"watchdog: \d+ms", "watchdog: 6s", text, count=1)
    if not fifo:
        text = text.replace("plc: {", "plc: {realtime: false, ", 1)
    text += (f"opcua:\n  endpoint: opc.tcp://127.0.0.1:{free_port()}\n  sample: 50ms\n"
             f"  feed: {directory}/feed.sock\n  security: {{policies: [None]}}\n"
             f"mqtt:\n  brokers: [mqtt://127.0.0.1:{broker}]\n  group_id: Bench\n"
             "  edge_node_id: side\n  sample: 50ms\n"
             "web:\n  listen: 127.0.0.1:0\n  sample: 50ms\n")
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    return path


def start_broker(directory: str) -> tuple[subprocess.Popen[bytes], int]:
    port = free_port()
    conf = os.path.join(directory, "mosquitto.conf")
    with open(conf, "w", encoding="utf-8") as f:
        f.write(("user root\n" if os.geteuid() == 0 else "")
                + f"listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
    p = subprocess.Popen([MOSQUITTO, "-c", conf], stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
    return p, port


@dataclass
class Side:
    """A side process started for a window: its stderr lines kept, when it said it
    serves."""

    proc: subprocess.Popen[str]
    t0: float
    pattern: re.Pattern[str]
    ready_s: float | None = None
    lines: list[str] = field(default_factory=list)

    def follow(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))
            if self.ready_s is None and self.pattern.search(line):
                self.ready_s = time.monotonic() - self.t0


def window(daemon: Daemon, seconds: float, side: str | None, path: str) -> dict[str, Any]:
    """The scan's figures over a window (statistics reset in the scan thread at its
    start): ``seconds`` long; with ``side``, ``softplc SIDE PLANT`` started at its start,
    and the window lasts until ``seconds`` after the process says it serves (at most
    MAX_WINDOW_S)."""
    stats = daemon.scan_stats
    daemon.call(stats.reset)
    t0 = time.monotonic()
    started = None
    if side is not None:
        proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", side, path], cwd=ROOT,
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        started = Side(proc, t0, SERVING[side])
        threading.Thread(target=started.follow, daemon=True).start()
        while started.ready_s is None and time.monotonic() - t0 < MAX_WINDOW_S:
            time.sleep(0.1)
        time.sleep(seconds)
    else:
        time.sleep(seconds)
    length = time.monotonic() - t0
    count, overruns = daemon.call(lambda: (stats.count, stats.overruns))
    late, scan = stats.lateness(), stats.scan()
    if started is not None:
        end_process(started.proc, 30.0)
    return {"seconds": length, "cycles": count, "overruns": overruns,
            "late_p99": late.p99 / 1e6,
            "late_max": late.max / 1e6, "scan_max": scan.max / 1e6,
            "ready": None if started is None else started.ready_s,
            "said": [] if started is None or started.ready_s is not None
            else started.lines[-3:]}


def busy(n: int) -> list[subprocess.Popen[bytes]]:
    """``n`` processes that keep a core busy (nice 0), for the whole run."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--testers", default="2", help="comma-separated plant sizes (testers)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--window", type=float, default=5.0,
                    help="seconds a start window goes on after the side process serves")
    ap.add_argument("--load", type=int, default=2, help="busy processes beside the run")
    ap.add_argument("--priority", default="fifo,normal")
    ap.add_argument("--sides", default="opcua,mqtt,web")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    tmp = tempfile.mkdtemp(prefix="bs", dir="/tmp")
    broker, port = start_broker(tmp)
    load = busy(args.load)
    worst: dict[tuple[str, str], float] = {}  # (priority, window kind) -> worst max, ms
    try:
        with open("/proc/loadavg", encoding="ascii") as f:
            avg = f.read().split()[0]
        out(f"{os.cpu_count()} cores, load average {avg} at the start, {args.load} busy "
            f"processes added; cycle 10 ms, windows of {args.window:g} s, "
            f"{args.repeat} repeats")
        out("| scan | testers | side | window | s | cycles | overruns | lateness p99 ms | "
            "lateness max ms | scan max ms | serving after s |")
        out("|---|---|---|---|---|---|---|---|---|---|---|")
        for priority in args.priority.split(","):
            for testers in (int(t) for t in args.testers.split(",")):
                directory = tempfile.mkdtemp(prefix=f"{priority}{testers}-", dir=tmp)
                path = side_plant(directory, testers, priority == "fifo", port)
                daemon, fs = start_daemon(path, testers, True)
                try:
                    for _ in range(args.repeat):
                        for side in args.sides.split(","):
                            length = args.window
                            for kind, who in (("start", side), ("control", None)):
                                # the control window as long as the start window before it
                                r = window(daemon, length, who, path)
                                length = r["seconds"]
                                top = max(r["late_max"], r["scan_max"])
                                key = (priority, kind)
                                worst[key] = max(worst.get(key, 0.0), top)
                                ready = "" if r["ready"] is None else f"{r['ready']:.1f}"
                                if who is not None and r["ready"] is None:
                                    ready = f"not in the window ({' / '.join(r['said'])})"
                                out(f"| {priority} | {testers} | {side} | {kind} | "
                                    f"{r['seconds']:.0f} | {r['cycles']} | {r['overruns']} | "
                                    f"{r['late_p99']:.2f} | {r['late_max']:.1f} | "
                                    f"{r['scan_max']:.1f} | {ready} |")
                    out(f"(faults of this controller: {len(daemon.faults)})")
                finally:
                    stop_daemon(daemon, fs)
        out("")
        out("| scan | window | worst max(lateness, scan) ms | " + " | ".join(
            f"watchdog {c} ms would trip" for c in CANDIDATES) + " |")
        out("|---|---|---|" + "---|" * len(CANDIDATES))
        for (priority, kind), ms in sorted(worst.items()):
            out(f"| {priority} | {kind} | {ms:.1f} | " + " | ".join(
                "yes" if ms > c else "no" for c in CANDIDATES) + " |")
    finally:
        for p in load:
            p.send_signal(signal.SIGTERM)
            p.wait()
        broker.terminate()
        broker.wait()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
