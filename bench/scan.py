"""Benchmark: the compiled engine against the same chart hand-written in Python.

Measures, for 1, 10, 100 and 1000 instances of the drawer tester of
``configs/drawer_tester/drawer_tester.yaml`` (seed 000, the complete chart):

- compiled: the whole ``softplc simulate`` run without a trace (``Simulation.run``): script
  events written into the sim driver's image, the plant cycle with its process image,
  inverted bindings and output copy, and the generated scan of every instance;
- hand-written: the same chart as an idiomatic Python state machine (one state variable,
  one class), fed the same input events through the same kind of image, with the same
  inversion and output copy.

Before timing, both run side by side and their outputs are compared every cycle over more
than one period of the input pattern (start, strokes, stop at end of cycle, failure by time
while opening and while closing, acknowledge, restart), so the programs are equivalent.
Also times the compilation of the chart (load, check and compile, in process). Not a test:
prints a table. Times are the best of ``--repeat`` runs.

    python -m bench.scan [--counts 1 10 100 1000] [--cycles N] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

from runtime.compiler.codegen import compile_grafcet
from runtime.engine.simulate import Simulation
from runtime.language.grafcetfile import GrafcetLoader
from runtime.language.yamlsrc import YMap, load_yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHART = os.path.join(ROOT, "configs", "drawer_tester", "drawer_tester.yaml")
CYCLE_NS = 10_000_000
PARADO, ABRIR, CERRAR, AVERIA = range(4)
TEN_S = 10_000_000_000
LIMIT = 1000


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


class HandDrawerTester:
    """configs/drawer_tester/drawer_tester.yaml written by hand: one state variable."""

    __slots__ = ("state", "t_enter", "s_paro", "s_cierres", "prev_marcha", "first",
                 "o_abrir", "o_cerrar", "o_parado", "o_test")

    def __init__(self) -> None:
        self.state = PARADO
        self.t_enter = 0
        self.s_paro = False
        self.s_cierres = 0
        self.prev_marcha = True  # no edge on the first scan
        self.first = True
        self.o_abrir = self.o_cerrar = self.o_parado = self.o_test = False

    def scan(self, now: int, up: int, paro: bool, marcha: bool, abierto: bool,
             cerrado: bool) -> None:
        if paro:
            self.s_paro = True
        if self.first:  # start-up: gsParado activated, its P1 runs, nothing fires
            self.first = False
            self.t_enter = now
            self.s_paro = False
            self.prev_marcha = marcha
            self._outputs(up)
            return
        state = self.state
        long = now - self.t_enter >= TEN_S
        start = marcha and not self.prev_marcha and not paro
        self.prev_marcha = marcha
        new = state
        if state == PARADO:
            if start:
                new = ABRIR
        elif state == ABRIR:
            if abierto:
                new = CERRAR
            elif long:
                new = AVERIA
        elif state == CERRAR:
            if cerrado and (self.s_paro or self.s_cierres >= LIMIT):
                new = PARADO
            elif cerrado:
                new = ABRIR
            elif long:
                new = AVERIA
        elif paro:
            new = PARADO
        if new != state:
            self.state = new
            self.t_enter = now
            if new == PARADO:  # entering gsParado
                self.s_paro = False
            elif state == PARADO:  # leaving it
                self.s_paro = False
                if self.s_cierres >= LIMIT:
                    self.s_cierres = 0
            if new == CERRAR:
                self.s_cierres += 1
            elif state == CERRAR and not cerrado:  # a stroke cut by a failure
                self.s_cierres -= 1
        self._outputs(up)

    def _outputs(self, up: int) -> None:
        st = self.state
        self.o_abrir = st == ABRIR
        self.o_cerrar = st == CERRAR
        self.o_test = st == ABRIR or st == CERRAR
        self.o_parado = (st == PARADO or (self.s_paro and up % 1_000_000_000 < 500_000_000)
                         or (st == AVERIA and up % 500_000_000 < 250_000_000))


PERIOD = 2700  # cycles


def pattern(phase: int) -> tuple[int, int, int, int]:
    """Physical inputs (NC stop, start, open, closed) at ``phase`` of the 27-s story:
    start, two strokes, stop pressed during the second (stop at end of cycle), restart and
    a drawer jammed while opening (failure after 10 s), acknowledge with the stop button,
    restart and a drawer jammed while closing (failure, stroke taken back), acknowledge."""
    def within(*spans: tuple[int, int]) -> bool:
        return any(a <= phase < b for a, b in spans)
    stop_nc = 0 if within((150, 155), (1400, 1405), (2600, 2605)) else 1
    start = 1 if within((10, 15), (300, 305), (1460, 1465)) else 0
    opened = 1 if within((40, 60), (120, 140), (1490, 1510)) else 0
    closed = 1 if within((0, 20), (80, 100), (160, 310), (1450, 1470), (2650, PERIOD)) else 0
    return stop_nc, start, opened, closed


def points(i: int) -> tuple[list[str], list[str]]:
    b = i * 10
    return [f"I{b + j}" for j in range(4)], [f"Q{b + j}" for j in range(4)]


def changes(n: int, cycles: int) -> list[tuple[int, list[tuple[str, int]]]]:
    """(cycle, [(point, value)]) where some instance's physical inputs change."""
    last: list[tuple[int, ...] | None] = [None] * n
    out_: list[tuple[int, list[tuple[str, int]]]] = []
    for k in range(cycles):
        row: list[tuple[str, int]] = []
        for i in range(n):
            now = pattern((k + 37 * i) % PERIOD)
            prev = last[i]
            if now != prev:
                ins, _ = points(i)
                row += [(p, v) for j, (p, v) in enumerate(zip(ins, now, strict=True))
                        if prev is None or prev[j] != v]
                last[i] = now
        if row:
            out_.append((k, row))
    return out_


def write_files(d: str, n: int, cycles: int) -> tuple[str, str]:
    plant = ["plc: {cycle: 10ms, watchdog: 100ms}", "drivers:", "  sim: {type: sim}",
             "instances:"]
    for i in range(n):
        ins, outs = points(i)
        plant += [f"  t{i}:", f"    grafcet: {CHART}", "    inputs:",
                  f"      iParo: {{from: sim.{ins[0]}, invert: true}}",
                  f"      iMarcha: sim.{ins[1]}", f"      iAbierto: sim.{ins[2]}",
                  f"      iCerrado: sim.{ins[3]}",
                  f"    outputs: {{oAbrir: sim.{outs[0]}, oCerrar: sim.{outs[1]}, "
                  f"oParado: sim.{outs[2]}, oTest: sim.{outs[3]}}}"]
    script = [f"cycles: {cycles}", "set:"]
    for k, row in changes(n, cycles):
        script.append(f"  - {{at: {k * 10}ms, " + ", ".join(f"sim.{p}: {v}" for p, v in row)
                      + "}")
    ppath, spath = os.path.join(d, "plant.yaml"), os.path.join(d, "script.yaml")
    with open(ppath, "w", encoding="utf-8") as f:
        f.write("\n".join(plant) + "\n")
    with open(spath, "w", encoding="utf-8") as f:
        f.write("\n".join(script) + "\n")
    return ppath, spath


def run_compiled(ppath: str, spath: str) -> float:
    """Seconds for the whole ``simulate`` run without a trace."""
    sim = Simulation(ppath, spath)
    t0 = time.perf_counter()
    for _ in sim.run(trace=False):
        pass
    return time.perf_counter() - t0


def compiled_outputs(ppath: str, spath: str, n: int) -> list[tuple[bool, ...]]:
    sim = Simulation(ppath, spath)
    keys = [f"sim.{q}" for i in range(n) for q in points(i)[1]]
    wanted = set(keys)
    sim.columns = [c for c in sim.columns if c[0] in wanted]
    return [tuple(bool(row[k]) for k in keys) for row in sim.run(trace=True)]


def run_hand(n: int, cycles: int, events: list[tuple[int, list[tuple[str, int]]]],
             record: list[tuple[bool, ...]] | None = None) -> float:
    """Seconds for the same run, hand-written: image, inversion, scans, output copy."""
    machines = [HandDrawerTester() for _ in range(n)]
    image_in: dict[str, int] = {}
    image_out: dict[str, bool] = {}
    for i in range(n):
        ins, outs = points(i)
        image_in.update(dict.fromkeys(ins, 0))
        image_out.update(dict.fromkeys(outs, False))
    plan = [(mach, *points(i)) for i, mach in enumerate(machines)]
    plan2 = [(m, ins[0], ins[1], ins[2], ins[3], outs[0], outs[1], outs[2], outs[3])
             for m, ins, outs in plan]
    ev, n_ev = 0, len(events)
    t0 = time.perf_counter()
    for k in range(cycles):
        while ev < n_ev and events[ev][0] <= k:
            for p, v in events[ev][1]:
                image_in[p] = v
            ev += 1
        now = up = k * CYCLE_NS
        for mach, ip, im, ia, ic, qa, qc, qp, qt in plan2:
            mach.scan(now, up, image_in[ip] == 0, image_in[im] != 0, image_in[ia] != 0,
                      image_in[ic] != 0)
            image_out[qa] = mach.o_abrir
            image_out[qc] = mach.o_cerrar
            image_out[qp] = mach.o_parado
            image_out[qt] = mach.o_test
        if record is not None:
            record.append(tuple(image_out[q] for _, ins, outs in plan for q in outs))
    return time.perf_counter() - t0


def compile_times(runs: int) -> list[float]:
    """Seconds to load, check and compile the chart, in process (no cache)."""
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        doc = load_yaml(CHART)
        assert isinstance(doc, YMap)
        compile_grafcet(GrafcetLoader(CHART, doc).load())
        times.append(time.perf_counter() - t0)
    return times


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--cycles", type=int, default=0, help="cycles per run (default: scaled)")
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    ct = compile_times(20)
    out(f"compile {os.path.relpath(CHART, ROOT)} (load + check + compile, in process, 20 runs): "
        f"min {min(ct) * 1e3:.1f} ms, median {statistics.median(ct) * 1e3:.1f} ms")
    out(f"{'instances':>9} {'cycles':>7} {'compiled scans/s':>17} {'hand scans/s':>13} "
        f"{'ratio':>6} {'us/inst':>8} {'ms/cycle':>9} {'hand ms/cycle':>14}")
    with tempfile.TemporaryDirectory() as d:
        for n in args.counts:
            cycles = args.cycles or max(500, 200_000 // n)
            # equivalence, over more than one period of the pattern (instances are
            # independent: 100 of them, at 100 phases of the pattern, are enough)
            check, n_check = PERIOD + 300, min(n, 100)
            ppath, spath = write_files(d, n_check, check)
            a = compiled_outputs(ppath, spath, n_check)
            b: list[tuple[bool, ...]] = []
            run_hand(n_check, check, changes(n_check, check), b)
            if a != b:
                k = next(i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y)
                out(f"MISMATCH with {n_check} instances at cycle {k}: compiled {a[k]} "
                    f"hand {b[k]}")
                return 1
            ppath, spath = write_files(d, n, cycles)
            events = changes(n, cycles)
            runs_c, runs_h = [], []
            for _ in range(args.repeat):  # interleaved: both see the same machine load
                runs_c.append(run_compiled(ppath, spath))
                runs_h.append(run_hand(n, cycles, events))
            t_c, t_h = min(runs_c), min(runs_h)
            scans = n * cycles
            out(f"{n:>9} {cycles:>7} {scans / t_c:>17,.0f} {scans / t_h:>13,.0f} "
                f"{t_c / t_h:>6.2f} {t_c / scans * 1e6:>8.2f} {t_c / cycles * 1e3:>9.4f} "
                f"{t_h / cycles * 1e3:>14.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
