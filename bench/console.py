"""Benchmark: what the console costs the scan. Cycle lateness of a running daemon with no
client, with a client streaming ``trace on``, and with that client plus a flood on the
serial console (1000 lines/s of commands, 2000-byte lines and binary garbage).

The plant is the console tests' one: two drawer testers on simulated I/O plus a chart
that changes every scan, so the trace streams a line per scan. The clients run in their
own processes (tests/console/flooder.py, at nice 10), as a laptop on the other end of
the cable would. Not a test: prints a table.

    python -m bench.console [--seconds 10] [--cycle 10ms] [--priority 50]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
from typing import Any

from tests.console.consolekit import Rig, make_rig

HERE = os.path.dirname(os.path.abspath(__file__))

FLOODER = os.path.join(HERE, "..", "tests", "console", "flooder.py")


def window(rig: Rig, seconds: float, start: list[subprocess.Popen[str]] | None = None
           ) -> dict[str, Any]:
    """Cycle statistics over ``seconds`` (reset in the scan thread at the start)."""
    stats = rig.daemon.scan_stats
    rig.daemon.call(stats.reset)
    time.sleep(seconds)
    count, overruns = rig.daemon.call(lambda: (stats.count, stats.overruns))
    late, scan = stats.lateness(), stats.scan()
    return {"cycles": count, "overruns": overruns, "p50": late.p50 / 1e3,
            "p99": late.p99 / 1e3, "max": late.max / 1e3, "scan_p99": scan.p99 / 1e3}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each phase")
    ap.add_argument("--cycle", default="10ms", help="the plant's cycle (10ms)")
    ap.add_argument("--priority", type=int, metavar="N",
                    help="run the scan thread SCHED_FIFO at this priority (needs the "
                         "privilege; keeps other jobs of a shared machine out of the figures)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    secs = args.seconds
    flooder = subprocess.Popen([sys.executable, FLOODER, "flood", str(secs), "1000"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert flooder.stdout is not None and flooder.stdin is not None
    port = json.loads(flooder.stdout.readline())["port"]
    rig = make_rig(serial_path=port, blink=True, cycle=args.cycle, manage_gc=True,
                   priority=args.priority)
    assert rig.socket_path is not None
    rows = []
    try:
        time.sleep(1.0)  # start-up (compilation, first allocations) out of the figures
        rows.append(("no client", window(rig, secs), ""))
        tracer = subprocess.Popen([sys.executable, FLOODER, "trace", rig.socket_path,
                                   str(secs + 0.5)], stdout=subprocess.PIPE, text=True)
        time.sleep(0.25)
        stats = window(rig, secs)
        traced = json.loads(tracer.communicate(timeout=60)[0])
        rows.append(("trace on (socket)", stats, f"{traced['trace_lines']} trace lines"))
        tracer = subprocess.Popen([sys.executable, FLOODER, "trace", rig.socket_path,
                                   str(secs + 0.5)], stdout=subprocess.PIPE, text=True)
        flooder.stdin.write("go\n")
        flooder.stdin.flush()
        time.sleep(0.25)
        stats = window(rig, secs - 0.5)
        flood = json.loads(flooder.communicate(timeout=60)[0])
        traced = json.loads(tracer.communicate(timeout=60)[0])
        rows.append(("trace on + serial flood", stats,
                     f"{traced['trace_lines']} trace lines; flood {flood['rate']} lines/s, "
                     f"{flood['sent_bytes'] / flood['seconds'] / 1e3:.0f} kB/s, "
                     f"{flood['errors']} errors answered"))
    finally:
        if flooder.poll() is None:
            flooder.kill()
        rig.close()
    out = sys.stdout
    prio = f"SCHED_FIFO {args.priority}" if args.priority else "normal priority"
    out.write(f"cycle {args.cycle}, {secs:g} s per phase, scan thread at {prio}; lateness "
              "and scan time in us\n\n")
    out.write(f"{'phase':26}{'cycles':>8}{'overruns':>10}{'late p50':>10}{'late p99':>10}"
              f"{'late max':>10}{'scan p99':>10}  clients\n")
    for name, s, note in rows:
        out.write(f"{name:26}{s['cycles']:>8}{s['overruns']:>10}{s['p50']:>10.0f}"
                  f"{s['p99']:>10.0f}{s['max']:>10.0f}{s['scan_p99']:>10.0f}  {note}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
