"""Benchmark: what the console costs the scan. Cycle lateness of a running daemon with no
client, with a client streaming ``trace on``, with that client plus a flood on the
serial console (1000 lines/s of commands, 2000-byte lines and binary garbage), and with
16 clients (8 TCP + 8 Unix socket) pipelining ``stats``, ``help`` and ``get`` of every
name as fast as the replies come (``mix``), or ``stats`` alone, or ``help`` alone (issue
12: no client can starve the scan).

The plant is the console tests' one: two drawer testers on simulated I/O plus a chart
that changes every scan, so the trace streams a line per scan. The clients run in their
own processes (tests/console/flooder.py, at nice 10), as a laptop on the other end of
the cable would. The garbage collector runs as in production (in the scan's idle time).
Not a test: prints a table.

    python -m bench.console [--seconds 60] [--cycle 10ms] [--fifo | --priority N]
                            [--phases quiet,trace,serial,mix,stats,help]
                            [--switch-interval MS]
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

from runtime.console.server import ConsoleServer
from runtime.language.model import ConsoleEntry
from tests.console.consolekit import Rig, make_rig

HERE = os.path.dirname(os.path.abspath(__file__))

FLOODER = os.path.join(HERE, "..", "tests", "console", "flooder.py")


def window(rig: Rig, seconds: float) -> dict[str, Any]:
    """Cycle statistics over ``seconds`` (reset in the scan thread at the start)."""
    stats = rig.daemon.scan_stats
    faults = len(rig.daemon.faults)  # watchdog faults (and any other) in the window
    rig.daemon.call(stats.reset)
    time.sleep(seconds)
    count, overruns = rig.daemon.call(lambda: (stats.count, stats.overruns))
    late, scan = stats.lateness(), stats.scan()
    return {"cycles": count, "faults": len(rig.daemon.faults) - faults,
            "overruns": overruns, "p50": late.p50 / 1e3,
            "p99": late.p99 / 1e3, "max": late.max / 1e3, "scan_p99": scan.p99 / 1e3}


#: the pipelining clients of a clients phase, per transport
CLIENTS_PER_TRANSPORT = 8
#: phases of pipelining clients -> what they send round and round (None: stats, help and
#: get of every name, the issue's mix); stats and help alone were the attacks of issue 12
CLIENT_PHASES: dict[str, list[str] | None] = {"mix": None, "stats": ["stats"],
                                              "help": ["help"]}


def pipeliners(addresses: list[str], commands: list[str], seconds: float
               ) -> list[subprocess.Popen[str]]:
    """One pipelining client process per address, connected (waiting for "go")."""
    procs = [subprocess.Popen([sys.executable, FLOODER, "pipeline", a, str(seconds),
                               *commands], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True) for a in addresses]
    for p in procs:
        assert p.stdout is not None
        json.loads(p.stdout.readline())
    return procs


def clients_phase(rig: Rig, tcp: str, secs: float, commands: list[str]
                  ) -> tuple[dict[str, Any], str]:
    """16 clients (8 TCP, 8 Unix socket) pipelining ``commands``."""
    assert rig.socket_path is not None
    procs = pipeliners([tcp] * CLIENTS_PER_TRANSPORT
                       + [rig.socket_path] * CLIENTS_PER_TRANSPORT, commands, secs)
    for p in procs:
        assert p.stdin is not None
        p.stdin.write("go\n")
        p.stdin.flush()
    stats = window(rig, secs)
    seen = [json.loads(p.communicate(timeout=secs + 60)[0]) for p in procs]
    ok = sum(c["ok"] for c in seen)
    refused = sum(c["refused"] for c in seen)
    lost = sum(c["sent"] - c["replies"] for c in seen)
    return stats, (f"{len(seen)} clients: {ok / secs:.0f} replies/s, {refused / secs:.0f} "
                   f"refusals/s ('too many requests'), {lost} lines unanswered")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each phase (60)")
    ap.add_argument("--cycle", default="10ms", help="the plant's cycle (10ms)")
    ap.add_argument("--priority", type=int, metavar="N",
                    help="run the scan thread SCHED_FIFO at this priority (the plant's "
                         "plc: realtime: priority key; needs the privilege)")
    ap.add_argument("--fifo", action="store_true", help="the same as --priority 50")
    ap.add_argument("--phases", default="quiet,trace,serial,mix,stats,help",
                    help="which phases, in this order (quiet,trace,serial,mix,stats,help)")
    ap.add_argument("--switch-interval", type=float, metavar="MS",
                    help="set the GIL switch interval after the daemon started (it sets "
                         "0.5 ms): to measure its effect")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    secs = args.seconds
    priority = args.priority or (50 if args.fifo else None)
    phases = args.phases.split(",")
    flooder = subprocess.Popen([sys.executable, FLOODER, "flood", str(secs), "1000"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert flooder.stdout is not None and flooder.stdin is not None
    port = json.loads(flooder.stdout.readline())["port"]
    rig = make_rig(serial_path=port, blink=True, cycle=args.cycle, manage_gc=True,
                   priority=priority)
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval / 1e3)
    tcp_server = ConsoleServer(rig.service, [ConsoleEntry("tcp", "127.0.0.1:0")])
    tcp_server.start()
    switch_ms = sys.getswitchinterval() * 1e3
    assert rig.socket_path is not None
    rows = []
    try:
        time.sleep(1.0)  # start-up (compilation, first allocations) out of the figures
        for phase in phases:
            if phase == "quiet":
                rows.append(("no client", window(rig, secs), ""))
            elif phase == "trace":
                tracer = subprocess.Popen([sys.executable, FLOODER, "trace",
                                           rig.socket_path, str(secs + 0.5)],
                                          stdout=subprocess.PIPE, text=True)
                time.sleep(0.25)
                stats = window(rig, secs)
                traced = json.loads(tracer.communicate(timeout=60)[0])
                rows.append(("trace on (socket)", stats,
                             f"{traced['trace_lines']} trace lines"))
            elif phase == "serial":
                rows.append(serial_phase(rig, flooder, secs))
            elif phase in CLIENT_PHASES:
                commands = CLIENT_PHASES[phase] or [
                    "stats", "help", *(f"get {n}" for n in rig.service.catalogue.names)]
                stats, note = clients_phase(rig, tcp_server.addresses[0], secs, commands)
                rows.append((f"16 clients: {phase}", stats, note))
            else:
                raise SystemExit(f"unknown phase {phase!r}")
    finally:
        if flooder.poll() is None:
            flooder.kill()
        tcp_server.stop()
        rig.close()
    out = sys.stdout
    prio = f"SCHED_FIFO {priority}" if priority else "normal priority"
    out.write(f"cycle {args.cycle}, {secs:g} s per phase, scan thread at {prio}, GIL "
              f"switch interval {switch_ms:g} ms; lateness and scan time in us\n\n")
    out.write(f"{'phase':26}{'cycles':>8}{'faults':>8}{'overruns':>10}{'late p50':>10}"
              f"{'late p99':>10}{'late max':>10}{'scan p99':>10}  clients\n")
    for name, s, note in rows:
        out.write(f"{name:26}{s['cycles']:>8}{s['faults']:>8}{s['overruns']:>10}"
                  f"{s['p50']:>10.0f}{s['p99']:>10.0f}{s['max']:>10.0f}"
                  f"{s['scan_p99']:>10.0f}  {note}\n")
    return 0


def serial_phase(rig: Rig, flooder: subprocess.Popen[str], secs: float
                 ) -> tuple[str, dict[str, Any], str]:
    """A client streaming ``trace on`` plus the flood on the serial console."""
    assert rig.socket_path is not None and flooder.stdin is not None
    tracer = subprocess.Popen([sys.executable, FLOODER, "trace", rig.socket_path,
                               str(secs + 0.5)], stdout=subprocess.PIPE, text=True)
    flooder.stdin.write("go\n")
    flooder.stdin.flush()
    time.sleep(0.25)
    stats = window(rig, secs - 0.5)
    flood = json.loads(flooder.communicate(timeout=secs + 60)[0])
    traced = json.loads(tracer.communicate(timeout=60)[0])
    return ("trace on + serial flood", stats,
            f"{traced['trace_lines']} trace lines; flood {flood['rate']} lines/s, "
            f"{flood['sent_bytes'] / flood['seconds'] / 1e3:.0f} kB/s, "
            f"{flood['errors']} errors answered")


if __name__ == "__main__":
    sys.exit(main())
