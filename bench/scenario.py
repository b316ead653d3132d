"""Benchmark: ``softplc test`` on the drawer tester, 10,000 scans of 10 ms (100 s of plant
time) on the virtual clock, in this process.

The scenario is written to a temporary directory: both testers of
configs/drawer_tester/plant_sim.yaml started at 0.5 s and cycled (a stroke every 300 ms)
for the whole run, with ``--expectations`` expectations: one ``at`` check a second, then
``never`` (the two contactors together), ``always`` and ``rises`` over the whole run. The
times, each the median of ``--repeat`` runs:

- load: the scenario and its plant read, the charts compiled with coverage counters;
- run: the scans on the virtual clock, the columns the expectations read recorded, the
  expectations checked (``runtime.scenario.run.play``);
- bare: the same plant and inputs through ``Simulation.run(trace=False)`` with no
  expectation (what ``softplc simulate`` without a trace does), for comparison.

Not a test: prints the numbers (docs/testing-charts.md, "Speed").

    python -m bench.scenario [--scans 10000] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

from runtime.engine.simulate import Simulation
from runtime.scenario.run import load_scenario, play
from runtime.scenario.spec import read_scenario

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PLANT = os.path.join(ROOT, "configs", "drawer_tester", "plant_sim.yaml")


def scenario_text(scans: int) -> str:
    """Both testers cycling for ``scans`` scans of 10 ms, with their expectations."""
    end = scans * 10  # ms
    lines = [f"plant: {PLANT}", f"cycles: {scans}", "set:",
             "  - {at: 0ms, sim.I0: 1, sim.I4: 1, tester1.iCerrado: 1, tester2.iCerrado: 1}",
             "  - {at: 500ms, tester1.iMarcha: 1, tester2.iMarcha: 1}",
             "  - {at: 700ms, tester1.iMarcha: 0, tester2.iMarcha: 0}"]
    t, strokes = 500, 0
    while t + 600 < end:
        for name in ("tester1", "tester2"):
            lines += [f"  - {{at: {t + 100}ms, {name}.iCerrado: 0}}",
                      f"  - {{at: {t + 300}ms, {name}.iAbierto: 1}}",
                      f"  - {{at: {t + 400}ms, {name}.iAbierto: 0}}",
                      f"  - {{at: {t + 600}ms, {name}.iCerrado: 1}}"]
        strokes += 1
        t += 600
    lines.append("expect:")
    for s in range(1, end // 1000):  # in each second: opening or closing
        lines.append(f"  - {{at: {s}s, expect: {{tester1.oTest: 1, tester2.oTest: 1}}}}")
    lines += ["  - {never: {tester1.oAbrir: 1, tester1.oCerrar: 1}}",
              "  - {never: {tester2.oAbrir: 1, tester2.oCerrar: 1}}",
              "  - {from: 500ms, always: {tester1.oParado: 0}}",
              "  - {never: {tester1.gsAveria.X: 1}}",
              f"  - {{rises: {{tester1.oCerrar: {strokes}, tester2.oCerrar: {strokes}}}}}"]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=10_000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "bench.test.yaml")
        with open(path, "w", encoding="utf-8") as f:
            f.write(scenario_text(args.scans))
        loads, runs, bares = [], [], []
        n_exp = failed = 0
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            sc = load_scenario(path)
            t1 = time.perf_counter()
            out = play(sc)
            t2 = time.perf_counter()
            loads.append(t1 - t0)
            runs.append(t2 - t1)
            n_exp, failed = len(out.cases), len(out.failed)
            spec = read_scenario(path)
            sim = Simulation(PLANT, cycles=args.scans, pdef=spec.pdef, changes=spec.changes)
            t3 = time.perf_counter()
            for _row in sim.run(trace=False):
                pass
            bares.append(time.perf_counter() - t3)
    med = statistics.median
    sys.stdout.write(
        f"drawer tester, 2 instances, {args.scans} scans, {n_exp} expectations "
        f"({failed} failed), median of {args.repeat}:\n"
        f"  load (read, compile with coverage) {med(loads):.3f} s\n"
        f"  run and check                      {med(runs):.3f} s "
        f"({args.scans / med(runs):,.0f} scans/s)\n"
        f"  total                              {med(loads) + med(runs):.3f} s\n"
        f"  bare simulation, no trace          {med(bares):.3f} s\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
