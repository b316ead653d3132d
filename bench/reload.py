"""Benchmark: what an online change costs a running controller (not a test: prints a table).

Runs the daemon in this process on simulated I/O (the Daemon, Scheduler and generated plant
cycle of ``softplc run --sim``) with N drawer testers (bench.jitter's plant and drawer
model, so the charts keep moving) at a 10 ms cycle, and changes the chart's time-outs
(``gsAbrir.T >= 10s`` <-> ``11s``, every instance affected) ``--repeat`` times with
``Daemon.reload``. For each reload:

- load: the plant file and its charts, parsed in a child process (``load_apart``);
- prepare: diff, compile and build the new plant, in the reload's worker thread;
- apply: ``runtime.change.apply`` plus the switch of every holder, in the scan thread
  between two cycles (``ReloadResult.swap_ms``);
- the swap cycle: the first cycle of the new program, woken after the apply: its wake-up
  lateness and its scan time;
- the cycles that ran while the worker prepared (they share the GIL with it): their p99 and
  maximum lateness;

against the p99 and maximum of the other cycles of the run (the quiet ones).

With ``--chain N`` the plant also runs a chart of N steps in a loop (bench/divergence.py's
``chain_text``, instance ``chain`` on the same sim driver), and each reload changes that
chart instead (the time constant of its first step: ``min`` 1 ms <-> 2 ms), so every reload
loads and compiles the large chart: the figures say whether a large chart's prepare holds up
the cycles (the scan shares the GIL with the reload's worker thread).

    python -m bench.reload [--testers 100] [--repeat 10] [--seconds 1] [--chain 2000]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable

from bench.divergence import chain_text
from bench.jitter import CHART, DrawerModel, plant_file
from runtime.controller.daemon import Daemon
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


class Recorder:
    """A daemon listener: (scan ns, lateness ns) of every cycle, by cycle index, and the
    index of the first cycle after each swap."""

    def __init__(self, daemon: Daemon) -> None:
        self.daemon = daemon
        self.cycles: dict[int, tuple[int, int]] = {}
        self.swaps: list[int] = []
        self.preparing: set[int] = set()
        self.in_prepare = False

    def __call__(self, n: int) -> None:  # scan thread, after cycle n - 1
        stats = self.daemon.scan_stats
        self.cycles[n - 1] = (stats.scan_last, stats.late_last)
        if self.in_prepare:
            self.preparing.add(n - 1)

    def hook(self, plant: Plant) -> Callable[[], None]:  # a ReloadHook
        self.in_prepare = False  # the worker is done preparing once hooks run

        def commit() -> None:  # scan thread, at the swap: the next cycle is the swap's
            self.swaps.append(self.daemon.scan_stats.count)
        return commit


def row(label: str, values: list[float]) -> None:
    """One line of the table: median, p99 and max of ``values`` (ms)."""
    s = sorted(values) or [0.0]
    p99 = s[min(len(s) - 1, int(0.99 * len(s)))]
    out(f"{label:36}{statistics.median(s):9.3f}{p99:9.3f}{s[-1]:9.3f}")


def rss_kib() -> int:
    """This process's resident memory (KiB, /proc/self/status VmRSS)."""
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--testers", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=1.0, help="between two reloads")
    ap.add_argument("--chain", type=int, default=0,
                    help="add a chart of N steps, the one each reload changes")
    args = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="reload-bench")
    try:
        chart = os.path.join(tmp, "drawer_tester.yaml")
        shutil.copy(CHART, chart)
        path = plant_file(tmp, args.testers, 10, False)
        with open(path, encoding="utf-8") as f:
            text = f.read().replace(CHART, chart)
        edited, swaps = chart, [("gsAbrir.T >= 10s", "gsAbrir.T >= 11s")]
        if args.chain:
            edited = os.path.join(tmp, "chain.yaml")
            with open(edited, "w", encoding="utf-8") as f:
                f.write(chain_text(args.chain).replace("  s1: {actions: [oMotor]}",
                                                       "  s1: {actions: [oMotor], min: 1ms}"))
            swaps = [("min: 1ms}", "min: 2ms}")]
            b = 8 * args.testers
            text += (f"  chain:\n    grafcet: {edited}\n    inputs: {{iGo: sim.I{b}}}\n"
                     f"    outputs: {{oMotor: sim.Q{b}}}\n")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text)
        daemon = Daemon(load_plant(path), sim=True)
        rec = Recorder(daemon)
        daemon.add_listener(DrawerModel(daemon, args.testers))
        daemon.on_reload(rec.hook)
        daemon.start()
        time.sleep(2.0)  # warm-up
        daemon.add_listener(rec)
        results = []
        rss_before = rss_kib()
        for i in range(args.repeat):
            time.sleep(args.seconds)
            with open(edited, encoding="utf-8") as f:
                src = f.read()
            a, b = swaps[0] if i % 2 == 0 else swaps[0][::-1]
            with open(edited, "w", encoding="utf-8") as f:
                f.write(src.replace(a, b))
            rec.in_prepare = True
            r = daemon.reload()
            if not r.applied:
                out(f"reload {i} refused: {r.refusals}")
                return 1
            results.append(r)
        time.sleep(args.seconds)
        rss_after = rss_kib()
        stats = daemon.scan_stats
        overruns = stats.overruns
        daemon.stop("bench")
        # the swap cycles are the cycle right after each commit; the quiet cycles exclude
        # them and the cycles run while a worker prepared
        swap = [rec.cycles[k] for k in rec.swaps if k in rec.cycles]
        prep = [rec.cycles[k] for k in rec.preparing if k in rec.cycles]
        quiet = [v for k, v in rec.cycles.items() if k not in rec.swaps
                 and k not in rec.preparing]
        chain = f" and a chart of {args.chain} steps" if args.chain else ""
        out(f"online change, {args.testers} drawer testers{chain}, cycle 10 ms, "
            f"{len(results)} reloads, {len(rec.cycles)} cycles recorded, "
            f"{overruns} overruns in all")
        out(f"{'(ms)':36}{'median':>9}{'p99':>9}{'max':>9}")
        row("load (child process)", [r.load_ms for r in results])
        row("prepare (worker thread)", [r.prepare_ms for r in results])
        row("apply + switch (scan thread)", [r.swap_ms for r in results])
        row("swap cycle: lateness", [v[1] / 1e6 for v in swap])
        row("swap cycle: scan time", [v[0] / 1e6 for v in swap])
        row(f"cycles during prepare ({len(prep)}): lateness", [v[1] / 1e6 for v in prep])
        row(f"cycles during prepare ({len(prep)}): scan", [v[0] / 1e6 for v in prep])
        row(f"other cycles ({len(quiet)}): lateness", [v[1] / 1e6 for v in quiet])
        row(f"other cycles ({len(quiet)}): scan", [v[0] / 1e6 for v in quiet])
        out(f"resident memory: {rss_before / 1024:.1f} MiB before the first reload, "
            f"{rss_after / 1024:.1f} MiB after the last "
            f"({(rss_after - rss_before) / max(1, len(results)):.0f} KiB per reload)")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        for t in threading.enumerate():  # nothing of ours should be left
            if t.name.startswith("softplc-") and t.is_alive():
                out(f"thread left: {t.name}")


if __name__ == "__main__":
    sys.exit(main())
