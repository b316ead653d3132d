"""Benchmark: what the console costs the scan. Cycle lateness of a running daemon with no
client, with a client streaming ``trace on``, with that client plus a flood on the
serial console (1000 lines/s of commands, 2000-byte lines and binary garbage), and with
16 clients (8 TCP + 8 Unix socket) pipelining ``stats``, ``help`` and ``get`` of every
name as fast as the replies come (``mix``), or ``stats`` alone, or ``help`` alone (issue
12: no client can starve the scan).

The plant is the console tests' one: two drawer testers on simulated I/O plus a chart
that changes every scan, so the trace streams a line per scan; its Unix socket and TCP
consoles are served by one server (one thread), as a plant's are. The clients run in
their own processes (tests/console/flooder.py, at nice 10, or ``--client-nice N``: 0 for
a local user's clients, the attack of issue 31), as a laptop on the other end of the
cable would. The garbage collector runs as in production (in the scan's idle time).

Besides the scan's own figures (overruns, lateness), each row splits the lateness of the
scan thread's wake-ups (tests/console/schedprobe.py): ``runq`` is the time it waited for a
CPU (the machine: other processes, the clients), ``blocked`` the time it was woken yet
waited for something of the process itself (the GIL held by a console thread). Not a
test: prints a table.

    python -m bench.console [--seconds 60] [--cycle 10ms] [--fifo | --priority N]
                            [--phases quiet,trace,serial,mix,stats,help]
                            [--switch-interval MS] [--client-nice N] [--repeat K]
                            [--warmup S]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

from runtime.controller.daemon import Daemon
from tests.console.consolekit import Rig, make_rig
from tests.console.schedprobe import SchedProbe

HERE = os.path.dirname(os.path.abspath(__file__))

FLOODER = os.path.join(HERE, "..", "tests", "console", "flooder.py")


#: records each wake-up of the scan thread (installed by main)
PROBE = SchedProbe()


def window(rig: Rig, seconds: float) -> dict[str, Any]:
    """``probed_window`` of the rig's daemon with PROBE."""
    return probed_window(rig.daemon, PROBE, seconds)


def probed_window(daemon: Daemon, probe: SchedProbe, seconds: float, cycle_ns: int = 0,
                  on_end: Callable[[], Any] | None = None) -> dict[str, Any]:
    """Cycle figures over ``seconds``: counters of the scan's own statistics (never
    reset: their window keeps the last 8192 cycles, as a daemon's that has run for a
    while, see --warmup), lateness of each wake-up from ``probe`` (installed on the
    daemon's scheduler), µs; with ``cycle_ns``, its wake-ups a cycle late or more
    (``missed``). ``on_end`` is called as the window ends, its result under "on_end"
    (another probe's stop). The figures are computed once every count is taken: their
    sorting (tens of ms of Python at a 1 ms cycle) holds the GIL, and counted in the
    window it made overruns of its own."""
    stats = daemon.scan_stats
    faults = len(daemon.faults)  # watchdog faults (and any other) in the window
    count, overruns = daemon.call(lambda: (stats.count, stats.overruns))
    probe.start()
    time.sleep(seconds)
    probe.on = False
    ended = on_end() if on_end is not None else None
    count2, overruns2 = daemon.call(lambda: (stats.count, stats.overruns))
    wakes = probe.wakes(cycle_ns)
    return {"on_end": ended, "cycles": count2 - count, "faults": len(daemon.faults) - faults,
            "overruns": overruns2 - overruns, "p50": wakes.late_p50,
            "p99": wakes.late_p99, "max": wakes.late_max, "runq_p99": wakes.runq_p99,
            "blocked_p99": wakes.blocked_p99, "blocked_max": wakes.blocked_max,
            "blocked_1ms": wakes.blocked_over_1ms, "missed": wakes.missed}


#: the pipelining clients of a clients phase, per transport
CLIENTS_PER_TRANSPORT = 8
#: phases of pipelining clients -> what they send round and round (None: stats, help and
#: get of every name, the issue's mix); stats and help alone were the attacks of issue 12
CLIENT_PHASES: dict[str, list[str] | None] = {"mix": None, "stats": ["stats"],
                                              "help": ["help"]}


def pipeliners(addresses: list[str], commands: list[str], seconds: float, nice: int = 10
               ) -> list[subprocess.Popen[str]]:
    """One pipelining client process per address, connected (waiting for "go")."""
    procs = [subprocess.Popen([sys.executable, FLOODER, "--nice", str(nice), "pipeline", a,
                               str(seconds), *commands], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True) for a in addresses]
    for p in procs:
        assert p.stdout is not None
        json.loads(p.stdout.readline())
    return procs


def clients_phase(rig: Rig, secs: float, commands: list[str], nice: int
                  ) -> tuple[dict[str, Any], str]:
    """16 clients (8 TCP, 8 Unix socket) pipelining ``commands``."""
    assert rig.socket_path is not None
    procs = pipeliners([rig.tcp_address] * CLIENTS_PER_TRANSPORT
                       + [rig.socket_path] * CLIENTS_PER_TRANSPORT, commands, secs, nice)
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
                         "plc: realtime: priority key; needs the privilege); 0: at normal "
                         "priority (realtime: false); default: the daemon's (SCHED_FIFO 50 "
                         "where permitted)")
    ap.add_argument("--fifo", action="store_true", help="the same as --priority 50")
    ap.add_argument("--warmup", type=float, default=1.0, metavar="S",
                    help="seconds run before the phases (1; 85 fills the 8192-cycle window "
                         "of a 10 ms cycle, as on a daemon that has run for a while)")
    ap.add_argument("--phases", default="quiet,trace,serial,mix,stats,help",
                    help="which phases, in this order (quiet,trace,serial,mix,stats,help)")
    ap.add_argument("--switch-interval", type=float, metavar="MS",
                    help="set the GIL switch interval after the daemon started (it sets "
                         "0.5 ms): to measure its effect")
    ap.add_argument("--client-nice", type=int, default=10, metavar="N",
                    help="nice level of the client processes (10; 0: a local user's, the "
                         "attack of issue 31)")
    ap.add_argument("--repeat", type=int, default=1, metavar="K",
                    help="run the phases K times in turn (1)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    secs = args.seconds
    priority = 50 if args.fifo else args.priority
    phases = args.phases.split(",") * args.repeat
    flooder = subprocess.Popen([sys.executable, FLOODER, "--nice", str(args.client_nice),
                                "flood", str(secs), "1000"],
                               stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert flooder.stdout is not None and flooder.stdin is not None
    port = json.loads(flooder.stdout.readline())["port"]
    rig = make_rig(serial_path=port, blink=True, cycle=args.cycle, manage_gc=True,
                   priority=priority, tcp=True, probe=PROBE)
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval / 1e3)
    switch_ms = sys.getswitchinterval() * 1e3
    assert rig.socket_path is not None
    rows = []
    try:
        time.sleep(args.warmup)  # start-up (compilation, first allocations) out of the
        # figures; and the cycles of a daemon that has run for a while
        sched = scan_policy(rig)
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
                stats, note = clients_phase(rig, secs, commands, args.client_nice)
                rows.append((f"16 clients: {phase}", stats, note))
            else:
                raise SystemExit(f"unknown phase {phase!r}")
    finally:
        if flooder.poll() is None:
            flooder.kill()
        rig.close()
    out = sys.stdout
    out.write(f"cycle {args.cycle}, {secs:g} s per phase, scan thread at {sched}, GIL "
              f"switch interval {switch_ms:g} ms, clients at nice {args.client_nice}; "
              "lateness and scan time in us; runq: waiting for a CPU, blocked: woken "
              "but waiting for the process (the GIL); >1ms: wake-ups blocked longer\n\n")
    out.write(f"{'phase':26}{'cycles':>8}{'faults':>8}{'overruns':>10}{'late p50':>10}"
              f"{'late p99':>10}{'late max':>10}{'runq p99':>10}"
              f"{'blk p99':>9}{'blk max':>9}{'>1ms':>6}  clients\n")
    for name, s, note in rows:
        out.write(f"{name:26}{s['cycles']:>8}{s['faults']:>8}{s['overruns']:>10}"
                  f"{s['p50']:>10.0f}{s['p99']:>10.0f}{s['max']:>10.0f}"
                  f"{s['runq_p99']:>10.0f}{s['blocked_p99']:>9.0f}"
                  f"{s['blocked_max']:>9.0f}{s['blocked_1ms']:>6}  {note}\n")
    return 0


def scan_policy(rig: Rig) -> str:
    """How the scan thread is scheduled: ``SCHED_FIFO 50`` or ``normal priority``."""
    thread = rig.daemon._thread
    assert thread is not None and thread.native_id is not None
    if os.sched_getscheduler(thread.native_id) == os.SCHED_FIFO:
        return f"SCHED_FIFO {os.sched_getparam(thread.native_id).sched_priority}"
    return "normal priority"


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
