"""Benchmark: how steadily ``softplc run`` holds its cycle (not a test: prints a table).

Runs the daemon in this process on simulated I/O (the same Daemon, Scheduler and generated
plant cycle as ``softplc run --sim``) for each combination of

- plant: the two drawer testers of configs/drawer_tester/plant_sim.yaml, or 100 testers;
- cycle: 1 ms and 10 ms;
- load: the other core idle, or loaded by a busy process;

and reports the wake-up lateness (p50, p99, p99.9, max), the scan time (p50, p99, max)
and the overruns. The drawers move: between cycles a model closes each tester's limit
switches after its contactor (open -> iAbierto, close -> iCerrado) and presses MARCHA now
and then, so the charts keep evolving (gsAbrir <-> gsCerrar) rather than idling.
Extra rows: Python's own garbage collector instead of the scheduler's idle-time collection
(``gc: python``), and SCHED_FIFO (needs root or CAP_SYS_NICE).

``--cpu`` measures instead the controller's fixed cost per cycle at 1 ms with one tester
and no drawer model (``run_cpu``): the CPU time of the scan thread (kernel side of the
sleep and wake-up included, from /proc/self/task/*/schedstat), of the watchdog thread and
of the whole process, per cycle over ``--seconds``; and the Python side alone on a virtual
clock (no sleep): the loop with the daemon's idle work, less the plant cycle itself.

    python -m bench.jitter [--seconds 60] [--quick] [--only LABEL] [--cpu [--repeat 5]]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

from runtime.controller.daemon import Daemon
from runtime.language.plantfile import load_plant

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHART = os.path.join(ROOT, "configs", "drawer_tester", "drawer_tester.yaml")


def plant_file(directory: str, n: int, cycle_ms: int, fifo: bool) -> str:
    lines = [f"plc: {{cycle: {cycle_ms}ms, watchdog: {max(50, 10 * cycle_ms)}ms"
             + (", realtime: {priority: 50}" if fifo else "") + "}",
             "drivers: {sim: {type: sim}}", "instances:"]
    for i in range(n):
        b = 8 * i
        lines += [f"  t{i}:", f"    grafcet: {CHART}",
                  f"    inputs: {{iParo: {{from: sim.I{b}, invert: true}}, iMarcha: "
                  f"sim.I{b + 1}, iAbierto: sim.I{b + 2}, iCerrado: sim.I{b + 3}}}",
                  f"    outputs: {{oAbrir: sim.Q{b}, oCerrar: sim.Q{b + 1}, oParado: "
                  f"sim.Q{b + 2}, oTest: sim.Q{b + 3}}}"]
    path = os.path.join(directory, f"plant_{n}_{cycle_ms}{'_fifo' if fifo else ''}.yaml")
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    return path


class DrawerModel:
    """The testers' drawers, moved between cycles in the scan thread (a daemon listener):
    the limit switches follow the contactors one cycle later; MARCHA is pressed every
    200 cycles; the NC stop buttons are released (physical 1)."""

    def __init__(self, daemon: Daemon, n: int) -> None:
        sim = daemon.plant.drivers["sim"]
        self.n = n
        for i in range(n):
            sim.inputs[f"I{8 * i}"] = 1
            sim.inputs[f"I{8 * i + 3}"] = 1
        # the images' value lists by the points' positions (drivers/image.py), as the
        # plant's cycle reads them: no lookup by name per cycle
        self.inp, self.out = sim.inputs.vals, sim.outputs.vals
        at, qt = sim.inputs.index, sim.outputs.index
        self.pos = [(at[f"I{8 * i + 1}"], at[f"I{8 * i + 2}"], at[f"I{8 * i + 3}"],
                     qt[f"Q{8 * i}"], qt[f"Q{8 * i + 1}"]) for i in range(n)]

    def __call__(self, cycle: int) -> None:
        inp, out = self.inp, self.out
        press = cycle % 200 < 5  # bits of the image hold bools (docs/drivers.md)
        for marcha, open_, closed, q_open, q_close in self.pos:
            inp[marcha] = press
            if out[q_open]:
                inp[open_], inp[closed] = True, False
            elif out[q_close]:
                inp[open_], inp[closed] = False, True


def run_one(path: str, n: int, seconds: float, manage_gc: bool) -> dict[str, Any]:
    daemon = Daemon(load_plant(path), sim=True, manage_gc=manage_gc)
    daemon.add_listener(DrawerModel(daemon, n))
    daemon.start()
    time.sleep(1.0)  # warm-up, not counted
    daemon.call(daemon.scan_stats.reset)
    time.sleep(seconds)
    stats = daemon.call(lambda: (daemon.scan_stats.lateness(), daemon.scan_stats.scan(),
                                 daemon.scan_stats.overruns, daemon.scan_stats.count,
                                 daemon.scan_stats.gc_runs))
    steps = {name: inst.active_steps() for name, inst in
             list(daemon.plant.instances.items())[:1]}
    daemon.stop("bench")
    late, scan, overruns, count, gc_runs = stats
    return {"late": late, "scan": scan, "overruns": overruns, "cycles": count,
            "gc_runs": gc_runs, "steps": steps}


def thread_cpu_ns(tid: int) -> int:
    """CPU time of thread ``tid`` of this process, ns (kernel side included)."""
    with open(f"/proc/self/task/{tid}/schedstat", encoding="ascii") as f:
        return int(f.read().split()[0])


def cpu_real(path: str, seconds: float) -> dict[str, float]:
    """µs of CPU per cycle: scan thread, watchdog thread, whole process (a real clock)."""
    daemon = Daemon(load_plant(path), sim=True)
    daemon.start()
    time.sleep(0.5)  # warm-up, not counted
    tids = {t.name: t.native_id for t in threading.enumerate()
            if t.name in ("softplc-scan", "softplc-watchdog") and t.native_id is not None}
    before = {k: thread_cpu_ns(v) for k, v in tids.items()}
    n0, p0 = daemon.scan_stats.count, time.process_time_ns()
    time.sleep(seconds)
    after = {k: thread_cpu_ns(v) for k, v in tids.items()}
    n1, p1 = daemon.scan_stats.count, time.process_time_ns()
    daemon.stop("bench")
    n = max(1, n1 - n0)
    out = {k.removeprefix("softplc-"): (after[k] - before[k]) / n / 1e3 for k in tids}
    out["process"] = (p1 - p0) / n / 1e3
    return out


def cpu_virtual(path: str, cycles: int = 50_000) -> dict[str, float]:
    """µs of CPU per cycle of the Python side on a virtual clock: the scheduler loop with
    the daemon's idle work and statistics, and the plant cycle alone for comparison."""
    now = [0]

    def clock() -> int:
        now[0] += 20_000  # every reading of the clock 20 µs later
        return now[0]

    def sleep_until(deadline: int) -> None:
        now[0] = max(now[0], deadline)

    daemon = Daemon(load_plant(path), sim=True, clock=clock)
    daemon.plant.open()
    sched = daemon.scheduler
    sched.sleep_until, sched.boot_clock = sleep_until, None
    sched.run(1000)  # warm-up
    t0 = time.process_time_ns()
    sched.run(cycles)
    loop = (time.process_time_ns() - t0) / cycles / 1e3
    cycle = daemon.plant.cycle
    t0 = time.process_time_ns()
    for _ in range(cycles):
        cycle(clock())
    plant = (time.process_time_ns() - t0) / cycles / 1e3
    daemon.plant.close()
    return {"loop": loop, "plant": plant, "fixed": loop - plant}


def main_cpu(seconds: float, repeat: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = plant_file(tmp, 1, 1, False)
        for _ in range(repeat):
            v = cpu_virtual(path)
            sys.stdout.write(f"virtual clock: loop {v['loop']:.2f} us/cycle, plant cycle "
                             f"{v['plant']:.2f}, controller fixed cost {v['fixed']:.2f}\n")
            r = cpu_real(path, seconds)
            sys.stdout.write("real 1 ms: " + ", ".join(
                f"{k} {x:.1f}" for k, x in r.items()) + " us CPU/cycle\n")
            sys.stdout.flush()


def busy_core() -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def _label(n: int, cycle_ms: int, loaded: bool, managed: bool, fifo: bool) -> str:
    return (f"{n:>3} inst {cycle_ms:>2} ms {'loaded' if loaded else 'idle  '} "
            f"{'gc:idle  ' if managed else 'gc:python'} {'FIFO' if fifo else '    '}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="measured time per row")
    ap.add_argument("--quick", action="store_true", help="5 s per row")
    ap.add_argument("--cpu", action="store_true",
                    help="the controller's CPU per cycle at 1 ms instead of the table")
    ap.add_argument("--repeat", type=int, default=5, help="--cpu: measurements")
    ap.add_argument("--only", default="", help="rows whose label contains this text, "
                    "e.g. '2 inst  1 ms loaded gc:idle   FIFO'")
    args = ap.parse_args()
    seconds = 5.0 if args.quick else args.seconds
    if args.cpu:
        main_cpu(seconds, args.repeat)
        return
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        combos: list[tuple[int, int, bool, bool, bool]] = []
        for n in (2, 100):
            for cycle_ms in (10, 1):
                for loaded in (False, True):
                    combos.append((n, cycle_ms, loaded, True, False))
        combos += [(2, 10, True, False, False), (100, 10, True, False, False),
                   (2, 1, True, True, True), (100, 1, True, True, True)]
        for n, cycle_ms, loaded, managed, fifo in combos:
            if args.only and args.only not in _label(n, cycle_ms, loaded, managed, fifo):
                continue
            path = plant_file(tmp, n, cycle_ms, fifo)
            load = busy_core() if loaded else None
            try:
                r = run_one(path, n, seconds, managed)
            finally:
                if load is not None:
                    load.kill()
                    load.wait()
            label = _label(n, cycle_ms, loaded, managed, fifo)
            late, scan = r["late"], r["scan"]
            rows.append(label)
            sys.stdout.write(
                f"{label} | late p50 {late.p50 / 1e3:7.1f} p99 {late.p99 / 1e3:7.1f} "
                f"p99.9 {late.p999 / 1e3:7.1f} max {late.max / 1e3:8.1f} us | scan p50 "
                f"{scan.p50 / 1e3:7.1f} p99 {scan.p99 / 1e3:7.1f} max {scan.max / 1e3:8.1f}"
                f" us | overruns {r['overruns']:>4} / {r['cycles']} | gc {r['gc_runs']}\n")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
