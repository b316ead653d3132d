"""Benchmark: what the console's streams cost the controller's process, alone (issue 40).
Not a test: prints a table.

The plant is bench/jitter.py's (``--testers`` drawer testers, default 100, the drawers
moving: bench/jitter.py's DrawerModel), run by the daemon's own scheduler on a virtual
clock (no sleep: bench/jitter.py's ``cpu_virtual``), ``--cycles`` cycles of 10 ms. Each
of ``--streams`` streams (``trace on``: every traced name; or ``watch`` of every
instance and driver with ``--watch``) is fed after every cycle as a console session
feeds it, and polled every ``--poll-every`` cycles (100 ms, as the console's servers
poll), in text mode. Columns, CPU time measured with ``time.thread_time_ns``:

- ``scan us/cycle``: what the scan thread does after each cycle for all the streams
  (``StreamTap.on_scan``; on code before it, each stream's own ``Stream.capture``);
- ``poll us``: one ``Stream.poll`` of one stream, on average;
- ``lines/s``: the lines the streams made, all together;
- ``% of a core``: both at a 10 ms cycle, all streams, per second of plant time.

    python -m bench.streams [--testers 100] [--streams 1,4] [--cycles 3000]
                            [--poll-every 10] [--watch]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable

from bench.jitter import DrawerModel, plant_file
from runtime.console import streams as console_streams
from runtime.console.streams import Stream
from runtime.controller.daemon import Daemon
from runtime.engine.names import Catalogue
from runtime.language.plantfile import load_plant

CYCLE_NS = 10_000_000


def scan_side(streams: list[Stream], daemon: Daemon) -> Callable[[int], None]:
    """What the scan thread runs after each cycle for ``streams``."""
    tap_class = getattr(console_streams, "StreamTap", None)
    if tap_class is not None:
        tap = tap_class(daemon)
        tap.streams = tuple(streams)  # registered by hand: the bench calls it itself
        on_scan: Callable[[int], None] = tap.on_scan
        return on_scan

    def each(scan: int) -> None:  # the code before StreamTap: a copy per stream
        for s in streams:
            s.capture(scan)  # type: ignore[attr-defined]
    return each


def row(path: str, testers: int, k: int, cycles: int, poll_every: int,
        watch: bool) -> str:
    now = [0]

    def clock() -> int:
        return now[0]

    def sleep_until(deadline: int) -> None:
        now[0] = max(now[0], deadline)

    daemon = Daemon(load_plant(path), sim=True, clock=clock, manage_gc=False)
    daemon.plant.open()
    sched = daemon.scheduler
    sched.sleep_until, sched.boot_clock = sleep_until, None
    sched.cycle_ns = CYCLE_NS
    daemon.add_listener(DrawerModel(daemon, testers))
    sched.run(300)  # warm-up: the drawers moving
    cat = Catalogue(daemon.plant)
    names = (cat.expand([*daemon.plant.instances, *daemon.plant.drivers]) if watch
             else cat.traced)
    streams = [Stream("watch" if watch else "trace", names, cat) for _ in range(k)]
    for s in streams:
        s.images.append(cat.capture(-1))
        s.last_scan = daemon.scan_stats.count
    on_scan = scan_side(streams, daemon)
    spent = {"scan": 0, "poll": 0, "polls": 0, "lines": 0}

    def after_cycle(scan: int) -> None:
        t0 = time.thread_time_ns()
        on_scan(scan)
        t1 = time.thread_time_ns()
        spent["scan"] += t1 - t0
        if scan % poll_every == 0:
            for s in streams:
                spent["lines"] += len(s.poll(lambda: now[0] / 1e9, False))
            spent["poll"] += time.thread_time_ns() - t1
            spent["polls"] += len(streams)
    daemon.add_listener(after_cycle)
    sched.run(cycles)
    daemon.plant.close()
    scan_us = spent["scan"] / cycles / 1e3
    poll_us = spent["poll"] / max(1, spent["polls"]) / 1e3
    seconds = cycles * CYCLE_NS / 1e9
    core = (spent["scan"] + spent["poll"]) / (seconds * 1e9) * 100
    return (f"{testers:>7} {len(names):>6} {k:>7} {scan_us:>13.1f} {poll_us:>8.0f} "
            f"{spent['lines'] / seconds:>8.0f} {core:>12.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--streams", default="1,4", help="numbers of streams, e.g. 1,4")
    ap.add_argument("--cycles", type=int, default=3000)
    ap.add_argument("--poll-every", type=int, default=10, metavar="N",
                    help="cycles between two polls of each stream (10: 100 ms)")
    ap.add_argument("--watch", action="store_true",
                    help="watch every instance and driver instead of trace on")
    args = ap.parse_args()
    sys.stdout.write(f"{'watch' if args.watch else 'trace on'}, 10 ms cycles, a poll every "
                     f"{args.poll_every} cycles\n")
    sys.stdout.write("testers  names streams scan us/cycle  poll us  lines/s  % of a core\n")
    with tempfile.TemporaryDirectory() as tmp:
        path = plant_file(tmp, args.testers, 10, False)
        for k in (int(x) for x in args.streams.split(",")):
            sys.stdout.write(row(path, args.testers, k, args.cycles, args.poll_every,
                                 args.watch) + "\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
