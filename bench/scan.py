"""Benchmark: scans per second of the compiled engine vs a hand-written state machine.

Runs the drawer tester (seed 000) for 1, 10, 100 and 1000 instances on simulated I/O, the
whole cycle included (driver image, bindings with inversion, scans, outputs), and the
same chart written by hand as an idiomatic Python state machine with the same I/O copy.
Both see the same input pattern and the outputs are compared every cycle, so the
comparison is between equivalent programs. Not a test: prints a table.

    python bench/scan.py [--cycles N] [--counts 1 10 100 1000]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from runtime.plant import Plant  # noqa: E402
from runtime.plantfile import load_plant  # noqa: E402

CHART = """\
grafcet: DrawerTester
inputs: [iParo, iMarcha, iAbierto, iCerrado]
outputs: [oAbrir, oCerrar, oParado, oTest]
memory:
  sParo: false
  sCierres: {init: 0, retain: true}
pre:
  - sParo.Set(1, iParo)
  - tAveriaAbrir := gsAbrir.T >= 10s
  - tAveriaCerrar := gsCerrar.T >= 10s
  - tParo := iCerrado·sParo + (sCierres >= 1000)
steps:
  gsParado: {initial: true, actions: ["P1 sParo := 0"]}
  gsAbrir:  {actions: [oAbrir, oTest]}
  gsCerrar: {actions: [oCerrar, oTest, "P1 sCierres := sCierres + 1"]}
  gsAveria: {}
transitions:
  - {from: gsParado, to: gsAbrir, when: "↑iMarcha·iParo'"}
  - {from: gsAbrir, to: gsCerrar, when: iAbierto}
  - {from: gsAbrir, to: gsAveria, when: tAveriaAbrir}
  - {from: gsCerrar, to: gsParado, when: tParo}
  - {from: gsCerrar, to: gsAbrir, when: iCerrado}
  - {from: gsCerrar, to: gsAveria, when: tAveriaCerrar}
  - {from: gsAveria, to: gsParado, when: "↑iMarcha·iParo'"}
post:
  - oParado := gsParado.X + sParo·Clock_1Hz
"""

PARADO, ABRIR, CERRAR, AVERIA = range(4)
TEN_S = 10_000_000_000


class HandDrawerTester:
    """The same chart, hand-written as a Python programmer would: one state variable."""

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
        if self.first:
            self.first = False
            self.t_enter = now
            self.s_paro = False  # P1 of gsParado
            self.prev_marcha = marcha
            self._outputs(up)
            return
        if paro:
            self.s_paro = True
        t = now - self.t_enter
        state = self.state
        start = marcha and not self.prev_marcha and not paro
        self.prev_marcha = marcha
        new = state
        if state == PARADO:
            if start:
                new = ABRIR
        elif state == ABRIR:
            if abierto:
                new = CERRAR
            elif t >= TEN_S:
                new = AVERIA
        elif state == CERRAR:
            if (cerrado and self.s_paro) or self.s_cierres >= 1000:
                new = PARADO
            elif cerrado:
                new = ABRIR
            elif t >= TEN_S:
                new = AVERIA
        elif start:
            new = PARADO
        if new != state:
            self.state = new
            self.t_enter = now
            if new == CERRAR:
                self.s_cierres += 1
            elif new == PARADO:
                self.s_paro = False
        self._outputs(up)

    def _outputs(self, up: int) -> None:
        st = self.state
        self.o_abrir = st == ABRIR
        self.o_cerrar = st == CERRAR
        self.o_test = st == ABRIR or st == CERRAR
        self.o_parado = st == PARADO or (self.s_paro and up % 1_000_000_000 < 500_000_000)


def plant_yaml(n: int) -> str:
    lines = ["plc: {cycle: 10ms, watchdog: 100ms}", "drivers:", "  sim: {type: sim}",
             "instances:"]
    for i in range(n):
        b = i * 10
        lines += [f"  t{i}:", "    grafcet: chart.yaml", "    inputs:",
                  f"      iParo: {{from: sim.I{b}, invert: true}}",
                  f"      iMarcha: sim.I{b + 1}", f"      iAbierto: sim.I{b + 2}",
                  f"      iCerrado: sim.I{b + 3}", "    outputs:",
                  f"      {{oAbrir: sim.Q{b}, oCerrar: sim.Q{b + 1}, oParado: sim.Q{b + 2}, "
                  f"oTest: sim.Q{b + 3}}}"]
    return "\n".join(lines) + "\n"


def pattern(k: int, i: int) -> tuple[int, int, int, int]:
    """Physical inputs (NC stop, start, open, closed) of instance i at cycle k."""
    phase = (k + 7 * i) % 400
    stop_nc = 0 if 300 <= phase < 305 else 1  # pressed briefly: NC contact opens
    start = 1 if 10 <= phase < 15 or 320 <= phase < 325 else 0
    opened = 1 if 40 <= phase < 60 or 140 <= phase < 160 else 0
    closed = 1 if 90 <= phase < 110 or 190 <= phase < 210 or phase >= 330 else 0
    return stop_nc, start, opened, closed


def run_compiled(n: int, cycles: int, inputs: list[list[tuple[int, ...]]],
                 record: bool) -> tuple[float, list[tuple[bool, ...]]]:
    with tempfile.TemporaryDirectory() as d:
        with open(os.path.join(d, "chart.yaml"), "w", encoding="utf-8") as f:
            f.write(CHART)
        with open(os.path.join(d, "plant.yaml"), "w", encoding="utf-8") as f:
            f.write(plant_yaml(n))
        plant = Plant(load_plant(os.path.join(d, "plant.yaml")), sim=True)
    plant.open()
    sim_in = plant.drivers["sim"].inputs
    sim_out = plant.drivers["sim"].outputs
    keys = [(f"I{i * 10}", f"I{i * 10 + 1}", f"I{i * 10 + 2}", f"I{i * 10 + 3}")
            for i in range(n)]
    outs = [(f"Q{i * 10}", f"Q{i * 10 + 1}", f"Q{i * 10 + 2}", f"Q{i * 10 + 3}")
            for i in range(n)]
    rec: list[tuple[bool, ...]] = []
    cyc = plant.cycle_ns
    t0 = time.perf_counter()
    for k in range(cycles):
        row = inputs[k]
        for (a, b, c, e), (p, m, o, cl) in zip(keys, row, strict=True):
            sim_in[a] = p
            sim_in[b] = m
            sim_in[c] = o
            sim_in[e] = cl
        plant.cycle(k * cyc)
        if record:
            rec.append(tuple(bool(sim_out[q]) for qs in outs for q in qs))
    return time.perf_counter() - t0, rec


def run_hand(n: int, cycles: int, inputs: list[list[tuple[int, ...]]],
             record: bool) -> tuple[float, list[tuple[bool, ...]]]:
    machines = [HandDrawerTester() for _ in range(n)]
    sim_in: dict[str, int] = {}
    sim_out: dict[str, bool] = {}
    keys = [(f"I{i * 10}", f"I{i * 10 + 1}", f"I{i * 10 + 2}", f"I{i * 10 + 3}")
            for i in range(n)]
    outs = [(f"Q{i * 10}", f"Q{i * 10 + 1}", f"Q{i * 10 + 2}", f"Q{i * 10 + 3}")
            for i in range(n)]
    plan = list(zip(machines, keys, outs, strict=True))
    rec: list[tuple[bool, ...]] = []
    start = None
    t0 = time.perf_counter()
    for k in range(cycles):
        row = inputs[k]
        for (a, b, c, e), (p, m, o, cl) in zip(keys, row, strict=True):
            sim_in[a] = p
            sim_in[b] = m
            sim_in[c] = o
            sim_in[e] = cl
        now = k * 10_000_000
        if start is None:
            start = now
        up = now - start
        for mach, (a, b, c, e), (qa, qc, qp, qt) in plan:
            mach.scan(now, up, sim_in[a] == 0, sim_in[b] != 0, sim_in[c] != 0, sim_in[e] != 0)
            sim_out[qa] = mach.o_abrir
            sim_out[qc] = mach.o_cerrar
            sim_out[qp] = mach.o_parado
            sim_out[qt] = mach.o_test
        if record:
            rec.append(tuple(bool(sim_out[q]) for qs in outs for q in qs))
    return time.perf_counter() - t0, rec


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=0, help="cycles per run (default: scaled)")
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 10, 100, 1000])
    args = ap.parse_args()
    print(f"{'instances':>9} {'cycles':>7} {'compiled scans/s':>17} {'hand scans/s':>13} "
          f"{'ratio':>6} {'us/inst':>8} {'ms/cycle':>9}")
    for n in args.counts:
        cycles = args.cycles or max(200, 200_000 // n)
        inputs = [[pattern(k, i) for i in range(n)] for k in range(cycles)]
        # equivalence check on a shorter run first
        check_cycles = min(cycles, 2000)
        _, a = run_compiled(n, check_cycles, inputs, record=True)
        _, b = run_hand(n, check_cycles, inputs, record=True)
        if a != b:
            k = next(i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y)
            print(f"MISMATCH at cycle {k}: compiled {a[k]} hand {b[k]}")
            return 1
        best_c = min(run_compiled(n, cycles, inputs, False)[0] for _ in range(3))
        best_h = min(run_hand(n, cycles, inputs, False)[0] for _ in range(3))
        scans = n * cycles
        print(f"{n:>9} {cycles:>7} {scans / best_c:>17,.0f} {scans / best_h:>13,.0f} "
              f"{best_c / best_h:>6.2f} {best_c / scans * 1e6:>8.2f} "
              f"{best_c / cycles * 1e3:>9.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
