"""Benchmark: what the event log (runtime/controller/events.py) costs the scan thread.

For 2 and 100 instances, the time per cycle of the daemon's listener ``EventWatcher``
alone, as the scan thread pays it after each scan (the log thread's formatting is not
counted: it is the other thread's work), in three cases:

- off: no ``log: steps`` (the listener still watches SFCError and overruns);
- on, quiet: ``log: steps`` on every instance, no step changes (the common cycle);
- on, changing: ``log: steps`` on every instance of a chart that changes step every scan
  (the worst case: every instance queues an event every cycle).

The plant's scan itself is timed alongside for scale. Virtual clock, simulated I/O, the
queue drained outside the timed part with logging disabled. Not a test: prints a table.

    python -m bench.events [--cycles N] [--repeat 3]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time

from runtime.controller.events import EventWatcher
from runtime.controller.stats import ScanStats
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TESTER = os.path.join(ROOT, "configs", "drawer_tester", "drawer_tester.yaml")
#: a chart that changes step every scan
BLINK = """\
grafcet: Blink
outputs: [oLamp]
steps:
  s0: {initial: true}
  s1: {actions: [oLamp]}
transitions:
  - {from: s0, to: s1, when: "1"}
  - {from: s1, to: s0, when: "1"}
"""
CYCLE_NS = 10_000_000


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def plant_text(chart: str, count: int, log_steps: bool) -> str:
    lines = ["plc: {cycle: 10ms" + (", log: steps" if log_steps else "") + "}",
             "drivers:", "  io: {type: sim}", "instances:"]
    for i in range(count):
        lines += [f"  i{i}:", f"    grafcet: {chart}"]
        if chart == TESTER:
            q = 4 * i
            lines += ["    inputs: {iParo: io.I0, iMarcha: io.I1, iAbierto: io.I2, "
                      "iCerrado: io.I3}",
                      f"    outputs: {{oAbrir: io.Q{q}, oCerrar: io.Q{q + 1}, "
                      f"oParado: io.Q{q + 2}, oTest: io.Q{q + 3}}}"]
        else:
            lines += [f"    outputs: {{oLamp: io.Q{i}}}"]
    return "\n".join(lines) + "\n"


def one_run(path: str, cycles: int) -> tuple[int, int]:
    """(scan ns, listener ns) in all over ``cycles`` cycles of a fresh plant."""
    plant = Plant(load_plant(path), sim=True, virtual=True)
    now = [0]
    w = EventWatcher(plant, ScanStats(), clock=lambda: now[0])
    scan_ns = watch_ns = 0
    clock = time.perf_counter_ns
    for n in range(1, cycles + 1):
        now[0] = n * CYCLE_NS
        t0 = clock()
        plant.cycle(now[0])
        t1 = clock()
        w(n)
        t2 = clock()
        scan_ns += t1 - t0
        watch_ns += t2 - t1
        if n % 256 == 0:
            w._drain()  # the log thread's work, not timed
    w.close()
    return scan_ns, watch_ns


def measure(path: str, cycles: int, repeat: int) -> tuple[float, float]:
    """(scan µs, listener µs) per cycle, best of ``repeat``."""
    runs = [one_run(path, cycles) for _ in range(repeat)]
    return (min(r[0] for r in runs) / cycles / 1e3, min(r[1] for r in runs) / cycles / 1e3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cycles", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    logging.disable(logging.CRITICAL)
    with tempfile.TemporaryDirectory() as tmp:
        blink = os.path.join(tmp, "blink.yaml")
        with open(blink, "w", encoding="utf-8") as f:
            f.write(BLINK)
        out("| instances | chart | log: steps | scan µs/cycle | listener µs/cycle |")
        out("|---|---|---|---|---|")
        for count in (2, 100):
            for chart, name, log_steps in ((TESTER, "drawer tester (quiet)", False),
                                           (TESTER, "drawer tester (quiet)", True),
                                           (blink, "blink (changes every scan)", False),
                                           (blink, "blink (changes every scan)", True)):
                path = os.path.join(tmp, "plant.yaml")
                with open(path, "w", encoding="utf-8") as f:
                    f.write(plant_text(chart, count, log_steps))
                scan, watch = measure(path, args.cycles, args.repeat)
                out(f"| {count} | {name} | {'on' if log_steps else 'off'} | "
                    f"{scan:.1f} | {watch:.2f} |")


if __name__ == "__main__":
    main()
