"""Benchmark: what the MQTT edge node costs the scan (issue 28). Not a test: prints a table.

The controller runs in this process as in bench/opcua.py (the same Daemon, Scheduler and
generated plant cycle as ``softplc run --sim``), with ``--testers`` drawer testers (default
100) whose drawers move, at a 10 ms cycle. Phases, each ``--seconds`` long:

- ``no feed``: the plant without its ``mqtt:`` section;
- ``feed only``: the controller's feed served, no edge node;
- ``edge node``: ``softplc mqtt PLANT`` in its own process (as its unit runs it, nice 10)
  publishing every change (``sample: 10ms``, the cycle) of the default groups to Debian's
  mosquitto on a loopback port, and a subscriber process (aiomqtt, nice 10) counting what
  arrives on ``spBv1.0/#``.

Per phase: the scan's wake-up lateness (p50, p99, max) and overruns over the window, the
controller's faults; for the edge node phase, the messages and bytes per second the
subscriber received, the edge node's CPU (percent of one core) and memory (VmRSS, VmHWM).

    python -m bench.mqtt [--seconds 60] [--testers 100] [--fifo] [--sample 10ms]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.jitter import plant_file
from bench.opcua import (
    end_process,
    out,
    proc_cpu_s,
    proc_mem_mib,
    scan_row,
    start_daemon,
    stop_daemon,
    window,
)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def mqtt_plant(directory: str, testers: int, broker: str, fifo: bool,
               sample: str = "10ms") -> str:
    """bench/jitter.py's plant of ``testers`` testers at 10 ms, with an ``mqtt:`` section
    reporting every ``sample`` (10 ms, the cycle: every change)."""
    path = plant_file(directory, testers, 10, fifo)
    with open(path, "a", encoding="utf-8") as f:
        f.write(mqtt_section(directory, broker, sample))
    return path


def mqtt_section(directory: str, broker: str, sample: str) -> str:
    """The plant's ``mqtt:`` section: ``broker``, a snapshot every ``sample``, the feed in
    ``directory``."""
    return (f"mqtt:\n  brokers: [{broker}]\n  group_id: Bench\n  edge_node_id: pi\n"
            f"  sample: {sample}\n  feed: {directory}/feed.sock\n")


async def count(host: str, port: int, seconds: float) -> dict[str, Any]:
    """Subscribe to spBv1.0/#; after "go" on stdin, count messages and bytes."""
    import aiomqtt

    async with aiomqtt.Client(host, port, identifier=f"bench-count-{os.getpid()}") as c:
        await c.subscribe("spBv1.0/#", qos=0)
        sys.stdout.write("ready\n")
        sys.stdout.flush()
        await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
        n = size = 0
        end = time.monotonic() + seconds

        async def take() -> None:
            nonlocal n, size
            async for m in c.messages:
                n += 1
                size += len(m.payload) if isinstance(m.payload, bytes | bytearray) else 0
        try:
            await asyncio.wait_for(take(), seconds)
        except TimeoutError:
            pass
        assert time.monotonic() >= end - 0.1
        return {"messages": n, "bytes": size}


def phase_edge(path: str, testers: int, seconds: float, host: str, port: int) -> dict[str, Any]:
    daemon, fs = start_daemon(path, testers, True)
    log = os.path.join(os.path.dirname(path), "mqtt.log")
    out(f"(the edge node's log: {log})")
    edge = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "runtime.cli", "mqtt",
                             path], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=open(log, "w"))  # noqa: SIM115
    sub = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "bench.mqtt", "--count",
                            json.dumps([host, port, seconds])], cwd=ROOT, text=True,
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert sub.stdout is not None and sub.stdin is not None
        assert sub.stdout.readline().strip() == "ready"
        time.sleep(3.0)  # the births, and the edge node settled
        cpu0 = proc_cpu_s(edge.pid)
        sub.stdin.write("go\n")
        sub.stdin.flush()
        w = window(daemon, seconds)
        cpu = proc_cpu_s(edge.pid) - cpu0
        rss, hwm = proc_mem_mib(edge.pid)
        got = json.loads(sub.stdout.readline())
        w.update(msg_s=got["messages"] / seconds, kib_s=got["bytes"] / seconds / 1024,
                 cpu_pct=100 * cpu / seconds, rss=rss, hwm=hwm, faults=len(daemon.faults))
        return w
    finally:
        sub.wait(60)
        end_process(edge, 30)
        stop_daemon(daemon, fs)


def row(label: str, r: dict[str, Any]) -> str:
    extra = " | | | | |"
    if "msg_s" in r:
        extra = (f" | {r['msg_s']:.0f} | {r['kib_s']:.0f} | {r['cpu_pct']:.0f} % | "
                 f"{r['rss']:.0f} ({r['hwm']:.0f}) |")
    return scan_row(label, r, extra)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--fifo", action="store_true",
                    help="the scan at SCHED_FIFO 50 (plc: realtime: needs root)")
    ap.add_argument("--sample", default="10ms",
                    help="mqtt: sample (default 10ms, the cycle: every change published)")
    ap.add_argument("--count", help=argparse.SUPPRESS)
    args = ap.parse_args()
    import logging
    logging.basicConfig(level=logging.ERROR)
    if args.count:
        host, port, seconds = json.loads(args.count)
        sys.stdout.write(json.dumps(asyncio.run(count(host, port, seconds))) + "\n")
        return
    from tests.mqtt.kit import Broker

    tmp = tempfile.mkdtemp(prefix="bm", dir="/tmp")
    broker = Broker(Path(tmp)).start()
    try:
        path = mqtt_plant(tmp, args.testers, broker.url, args.fifo, args.sample)
        out(f"{args.testers} drawer testers, cycle 10 ms, sample {args.sample}, "
            f"{args.seconds:g} s per phase, {os.cpu_count()} cores, scan "
            f"{'SCHED_FIFO 50' if args.fifo else 'SCHED_OTHER'}")
        out("| phase | cycles | overruns | faults | lateness p50 us | p99 us | max us | "
            "messages/s | KiB/s | edge node CPU | edge node RSS MiB (peak) |")
        out("|---|---|---|---|---|---|---|---|---|---|---|")
        for label, feed in (("no feed", False), ("feed only", True)):
            daemon, fs = start_daemon(path, args.testers, feed)
            try:
                out(row(label, window(daemon, args.seconds)))
            finally:
                stop_daemon(daemon, fs)
        out(row("edge node", phase_edge(path, args.testers, args.seconds, broker.bind,
                                        broker.port)))
    finally:
        broker.kill()


if __name__ == "__main__":
    main()
