"""Benchmark: what the web view costs the scan (issue 27). Not a test: prints a table.

The controller runs in this process as in bench/opcua.py (the same Daemon and generated
plant of ``--testers`` drawer testers whose drawers move, at a 10 ms cycle; the garbage
collector in the scan's idle time, as in production). Phases, each ``--seconds`` long:

- ``no feed``: the plant without its side processes' sections (no feed socket);
- ``feed only``: the controller's feed served (a snapshot every ``sample``), no reader;
- ``web + N pages``: ``softplc web PLANT`` in its own process (as its unit runs it) and
  ``--pages`` pages open: WebSocket clients in one process of their own (at nice 10) that
  read every message the page gets (not browsers: a browser would render on the laptop,
  not on the controller).

Per phase: the scan's wake-up lateness (p50, p99, max) and overruns over the window and the
controller's faults; for the web phase, the messages per second all pages received, the
web process's CPU (percent of one core) and its resident memory (VmRSS at the end, VmHWM
peak).

    python -m bench.web [--seconds 60] [--testers 100] [--pages 20] [--sample 100ms] [--fifo]
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
from typing import Any

from bench.jitter import plant_file
from bench.opcua import (
    ROOT,
    end_process,
    out,
    proc_cpu_s,
    proc_mem_mib,
    scan_row,
    start_daemon,
    stop_daemon,
    window,
)

#: how long the web view may take to serve its first frame, s
START_S = 60.0


def web_plant(directory: str, testers: int, port: int, sample: str, fifo: bool) -> str:
    """bench/jitter.py's plant of ``testers`` testers at 10 ms (SCHED_FIFO 50 with
    ``fifo``), plus a ``web:`` section."""
    path = plant_file(directory, testers, 10, fifo)
    with open(path, "a", encoding="utf-8") as f:
        f.write(web_section(directory, port, sample))
    return path


def web_section(directory: str, port: int, sample: str) -> str:
    """The plant's ``web:`` section: on 127.0.0.1:``port``, a snapshot every ``sample``,
    the feed in ``directory``."""
    return (f"web:\n  listen: 127.0.0.1:{port}\n  sample: {sample}\n"
            f"  feed: {directory}/feed.sock\n  max_pages: 200\n")


async def run_pages(url: str, pages: int, seconds: float, result: str) -> None:
    """``pages`` WebSocket pages reading everything for ``seconds``; the count of
    messages and bytes received written to ``result`` (JSON)."""
    import aiohttp

    counts = [0, 0]
    origin = url.rstrip("/")

    async def page(s: aiohttp.ClientSession) -> None:
        async with s.ws_connect(url + "ws", headers={"Origin": origin}) as ws:
            async for msg in ws:
                counts[0] += 1
                counts[1] += len(msg.data)
    async with aiohttp.ClientSession() as s:
        tasks = [asyncio.create_task(page(s)) for _ in range(pages)]
        await asyncio.sleep(seconds)
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
    with open(result, "w", encoding="utf-8") as f:
        json.dump({"messages": counts[0], "bytes": counts[1]}, f)


def wait_serving(url: str, deadline: float) -> None:
    import urllib.request

    while True:
        try:
            with urllib.request.urlopen(url + "api/plant", timeout=5) as r:
                if r.status == 200:
                    return
        except OSError:
            pass
        if time.monotonic() > deadline:
            raise RuntimeError("softplc web did not serve its page")
        time.sleep(0.2)


def phase_web(path: str, testers: int, pages: int, seconds: float, url: str,
              tmp: str) -> dict[str, Any]:
    daemon, fs = start_daemon(path, testers, True)
    web = subprocess.Popen([sys.executable, "-m", "runtime.cli", "web", path], cwd=ROOT,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    result = os.path.join(tmp, "pages.json")
    reader = None
    try:
        wait_serving(url, time.monotonic() + START_S)
        cfg = json.dumps({"url": url, "pages": pages, "seconds": seconds + 2,
                          "result": result})
        reader = subprocess.Popen(["nice", "-n", "10", sys.executable, "-m", "bench.web",
                                   "--reader", cfg], cwd=ROOT)
        time.sleep(2.0)  # the pages open and get their whole frame
        cpu0 = proc_cpu_s(web.pid)
        r = window(daemon, seconds)
        cpu1 = proc_cpu_s(web.pid)
        r["rss"], r["hwm"] = proc_mem_mib(web.pid)
        r["cpu_pct"] = 100 * (cpu1 - cpu0) / seconds
        reader.wait(seconds + 60)
        with open(result, encoding="utf-8") as f:
            got = json.load(f)
        r["msg_s"] = got["messages"] / (seconds + 2)
        r["kib_s"] = got["bytes"] / 1024 / (seconds + 2)
        return r
    finally:
        if reader is not None and reader.poll() is None:
            end_process(reader)
        end_process(web)
        stop_daemon(daemon, fs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--pages", type=int, default=20)
    ap.add_argument("--sample", default="100ms")
    ap.add_argument("--fifo", action="store_true",
                    help="the scan at SCHED_FIFO 50 (plc: realtime: needs root)")
    ap.add_argument("--reader", help=argparse.SUPPRESS)
    args = ap.parse_args()
    import logging
    logging.basicConfig(level=logging.ERROR)
    if args.reader:
        cfg = json.loads(args.reader)
        asyncio.run(run_pages(cfg["url"], cfg["pages"], cfg["seconds"], cfg["result"]))
        return
    from tests.opcua.kit import free_port

    tmp = tempfile.mkdtemp(prefix="bw", dir="/tmp")
    port = free_port()
    path = web_plant(tmp, args.testers, port, args.sample, args.fifo)
    url = f"http://127.0.0.1:{port}/"
    out(f"{args.testers} drawer testers, cycle 10 ms, sample {args.sample}, "
        f"{args.seconds:g} s per phase, {os.cpu_count()} cores, scan "
        f"{'SCHED_FIFO 50' if args.fifo else 'SCHED_OTHER'}")
    out("| phase | cycles | overruns | faults | lateness p50 us | p99 us | max us | "
        "messages/s (all pages) | KiB/s | web CPU | web RSS MiB (peak) |")
    out("|---|---|---|---|---|---|---|---|---|---|---|")
    for label, feed in (("no feed", False), ("feed only", True)):
        daemon, fs = start_daemon(path, args.testers, feed)
        try:
            out(scan_row(label, window(daemon, args.seconds), " | | | | |"))
        finally:
            stop_daemon(daemon, fs)
    r = phase_web(path, args.testers, args.pages, args.seconds, url, tmp)
    out(scan_row(f"web + {args.pages} pages", r,
                 f" | {r['msg_s']:.0f} | {r['kib_s']:.0f} | {r['cpu_pct']:.0f} % | "
                 f"{r['rss']:.0f} ({r['hwm']:.0f}) |"))


if __name__ == "__main__":
    main()
