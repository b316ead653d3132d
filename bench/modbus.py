"""Benchmark: what the Modbus/TCP server costs the scan, and how many requests it serves
(issue 41). Not a test: prints a table.

The controller runs in this process as in bench/opcua.py (the Daemon, Scheduler and
generated plant cycle of ``softplc run --sim``, the garbage collector in the scan's idle
time) with ``--testers`` drawer testers (default 100) whose drawers move, at a 10 ms
cycle, and its feed; ``softplc modbus PLANT`` runs in its own process, at niceness 10 as
its unit runs it, serving the I/O list (400 discrete inputs, 400 coils) and the testers'
stroke counters as input registers 0-99. Phases, each ``--seconds`` long, with the server
up throughout:

- ``no clients``: the control phase;
- ``10 panels``: ``--clients`` client processes (at niceness 10), each reading the 100
  input registers in one request every 100 ms, as HMI panels poll;
- ``10 flat out``: the same clients asking back to back, as fast as the server answers
  (the plant's ``limits: rate`` raised out of the way: the server's capacity).

Per phase: the scan's wake-up lateness (p50, p99, max) and overruns over the window (from
the scan statistics' ring: never reset, the feed numbers its frames by the scan count),
the requests answered per second (all clients), the slowest answer a client waited for,
and the server process's CPU (utime + stime over the window, percent of one core). The
lateness ratios are against the control phase of the same run. All processes share this
machine's cores: on a controller the panels are other machines, so the rows here are the
harder case.

    python -m bench.modbus [--seconds 20] [--testers 100] [--clients 10] [--fifo]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import struct
import subprocess
import sys
import tempfile
import time
from typing import Any

from bench.jitter import DrawerModel, plant_file
from bench.opcua import window as scan_window
from drivers.modbus_frame import mbap_frame, read_pdu
from runtime.controller.daemon import Daemon
from runtime.controller.feed import FeedServer
from runtime.language.plantfile import load_plant

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: clock ticks per second of /proc/PID/stat times
TICKS = os.sysconf("SC_CLK_TCK")
#: registers a panel reads in one request
REGISTERS = 100


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def modbus_plant(directory: str, testers: int, port: int, fifo: bool) -> str:
    """bench/jitter.py's plant, plus a ``modbus:`` section: the I/O list by default and
    each tester's stroke counter at an input register."""
    path = plant_file(directory, testers, 10, fifo)
    entries = "".join(f"    t{i}.sCierres: IR{i}\n" for i in range(testers))
    with open(path, "a", encoding="utf-8") as f:
        f.write(f"modbus:\n  listen: 127.0.0.1:{port}\n  sample: 50ms\n"
                f"  feed: {directory}/feed.sock\n  limits: {{rate: 100000, connections: 64}}\n"
                f"  map:\n{entries}")
    return path


def proc_cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime


# -- a client process ------------------------------------------------------------------
def run_client(port: int, period: float, seconds: float) -> None:
    """Read REGISTERS input registers every ``period`` s (0: back to back); say "ready",
    wait for a line, poll for ``seconds``, print the answers and the slowest one."""
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    f = s.makefile("rb")
    sys.stdout.write("ready\n")
    sys.stdout.flush()
    sys.stdin.readline()
    answered = refused = 0
    worst = 0.0
    end = time.monotonic() + seconds
    nxt = time.monotonic()
    k = 0
    while time.monotonic() < end:
        k = (k + 1) & 0xFFFF
        t0 = time.monotonic()
        s.sendall(mbap_frame(k, 1, read_pdu(4, 0, REGISTERS)))
        head = f.read(7)
        body = f.read(struct.unpack(">H", head[4:6])[0] - 1)
        worst = max(worst, time.monotonic() - t0)
        if body[0] == 4:
            answered += 1
        else:
            refused += 1
        if period:
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))
    s.close()
    sys.stdout.write(json.dumps({"answered": answered, "refused": refused,
                                 "worst_ms": worst * 1e3}) + "\n")
    sys.stdout.flush()


def wait_serving(port: int, deadline: float) -> None:
    while True:
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=2) as s:
                s.sendall(mbap_frame(1, 1, read_pdu(4, 0, 1)))
                if s.recv(64)[7:8] == b"\x04":
                    return
        except OSError:
            pass
        if time.monotonic() > deadline:
            raise TimeoutError(f"127.0.0.1:{port}: not serving")
        time.sleep(0.2)


def phase(daemon: Daemon, server: subprocess.Popen[bytes], port: int, clients: int,
          period: float | None, seconds: float) -> dict[str, Any]:
    """One phase: ``clients`` clients polling every ``period`` s (None: no client)."""
    procs: list[subprocess.Popen[str]] = []
    if period is not None:
        for _ in range(clients):
            p = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "bench.modbus",
                                  "--client", json.dumps([port, period, seconds])],
                                 cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                 text=True)
            assert p.stdout is not None and p.stdin is not None
            assert p.stdout.readline().strip() == "ready"
            procs.append(p)
        for p in procs:
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
    cpu0 = proc_cpu_s(server.pid)
    row = scan_window(daemon, seconds)
    row["server_cpu"] = 100 * (proc_cpu_s(server.pid) - cpu0) / seconds
    answered = refused = 0
    worst = 0.0
    for p in procs:
        o, _ = p.communicate(timeout=seconds + 60)
        r = json.loads(o.strip().splitlines()[-1])
        answered += r["answered"]
        refused += r["refused"]
        worst = max(worst, r["worst_ms"])
    row.update({"rate": answered / seconds, "refused": refused, "worst_ms": worst})
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--fifo", action="store_true", help="the scan at SCHED_FIFO 50, as "
                                                        "softplc@.service runs it")
    ap.add_argument("--client", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client:
        port, period, seconds = json.loads(args.client)
        run_client(port, period, seconds)
        return 0
    tmp = tempfile.mkdtemp(prefix="softplc-bench-modbus-")
    port = free_port()
    path = modbus_plant(tmp, args.testers, port, args.fifo)
    pdef = load_plant(path)
    daemon = Daemon(pdef, sim=True, manage_gc=True)
    daemon.add_listener(DrawerModel(daemon, args.testers))
    feed_def = pdef.feed()
    assert feed_def is not None
    fs = FeedServer(daemon, feed_def)
    fs.start()
    daemon.start()
    server = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "runtime.cli",
                               "modbus", path], cwd=ROOT, stdout=subprocess.DEVNULL,
                              stderr=open(os.path.join(tmp, "server.log"), "wb"))  # noqa: SIM115
    rows: dict[str, dict[str, Any]] = {}
    try:
        wait_serving(port, time.monotonic() + 120)
        time.sleep(1.0)  # warm-up, not counted
        rows["no clients"] = phase(daemon, server, port, args.clients, None, args.seconds)
        rows[f"{args.clients} panels, 100 ms"] = phase(daemon, server, port, args.clients,
                                                       0.1, args.seconds)
        rows[f"{args.clients} flat out"] = phase(daemon, server, port, args.clients, 0.0,
                                                 args.seconds)
    finally:
        server.terminate()
        server.wait(30)
        fs.stop()
        daemon.stop("bench")
    base = rows["no clients"]
    out(f"{args.testers} testers, 10 ms cycle{' (SCHED_FIFO 50)' if args.fifo else ''}, "
        f"{REGISTERS} input registers per request, {args.seconds:g} s per phase "
        f"(server log: {tmp}/server.log)")
    out(f"{'phase':<22} {'req/s':>8} {'worst ms':>9} {'server CPU':>10} {'late p50':>9} "
        f"{'p99 µs':>8} {'max µs':>8} {'p99 ratio':>9} {'overruns':>8}")
    for name, r in rows.items():
        ratio = r["p99"] / base["p99"] if base["p99"] else float("nan")
        out(f"{name:<22} {r['rate']:>8.0f} {r['worst_ms']:>9.1f} {r['server_cpu']:>9.0f}% "
            f"{r['p50']:>9.0f} {r['p99']:>8.0f} {r['max']:>8.0f} {ratio:>8.2f}x "
            f"{r['overruns']:>8}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
