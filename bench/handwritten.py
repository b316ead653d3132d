"""The drawer tester chart written by hand, the baselines of ``bench.scan``.

Two versions of ``configs/drawer_tester/drawer_tester.yaml`` (seed 000, the complete chart),
each running a whole simulated plant of ``n`` testers on the same scripted input changes:

- :func:`run_hand`: an idiomatic Python state machine (one object per tester, one method
  call per scan) reading and writing string-keyed dict images, as the compiled plant did;
- :func:`run_inline`: the same chart as an ordinary inline loop over the instances (no call
  per instance, the state in plain lists and locals, the process image as plain lists
  indexed by integers resolved once before the loop).

Both can record, cycle by cycle, every output, step flag and memory of every tester
(:data:`FIELDS`), so ``bench.scan`` checks them against the compiled plant before timing.
Point ``I{10i + j}`` / ``Q{10i + j}`` of the sim driver is input / output ``j`` of tester i.
"""

from __future__ import annotations

import time

CYCLE_NS = 10_000_000  # the plant's cycle: 10 ms
PARADO, ABRIR, CERRAR, AVERIA = range(4)  # the steps, in file order
TEN_S = 10_000_000_000  # failure by time (ns)
LIMIT = 1000  # closes per test

#: what a record holds per tester and cycle, in this order
FIELDS = ("oAbrir", "oCerrar", "oParado", "oTest", "gsParado.X", "gsAbrir.X", "gsCerrar.X",
          "gsAveria.X", "sParo", "sCierres")

#: (cycle, [(point, value)]): the input points that change at the start of that cycle
Events = list[tuple[int, list[tuple[str, int]]]]
#: per cycle, the FIELDS of every tester one after the other
Record = list[tuple[bool | int, ...]]


def points(i: int) -> tuple[list[str], list[str]]:
    """Input points (NC stop, start, open, closed) and output points (open, close, stopped
    pilot, test pilot) of tester ``i`` on the sim driver."""
    b = i * 10
    return [f"I{b + j}" for j in range(4)], [f"Q{b + j}" for j in range(4)]


def point_index(point: str) -> int:
    """Index of ``I{10i + j}`` / ``Q{10i + j}`` in a list image of 4 points per tester."""
    k = int(point[1:])
    return 4 * (k // 10) + k % 10


class HandDrawerTester:
    """configs/drawer_tester/drawer_tester.yaml written by hand: one state variable."""

    __slots__ = ("state", "t_enter", "s_paro", "s_cierres", "prev_marcha", "first",
                 "o_abrir", "o_cerrar", "o_parado", "o_test")

    def __init__(self, s_cierres: int = 0) -> None:
        self.state = PARADO
        self.t_enter = 0
        self.s_paro = False
        self.s_cierres = s_cierres
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

    def fields(self) -> tuple[bool | int, ...]:
        """This tester's :data:`FIELDS` now."""
        st = self.state
        return (self.o_abrir, self.o_cerrar, self.o_parado, self.o_test, st == PARADO,
                st == ABRIR, st == CERRAR, st == AVERIA, self.s_paro, self.s_cierres)


def run_hand(n: int, cycles: int, events: Events, record: Record | None = None,
             counts: list[int] | None = None) -> float:
    """Seconds for the run with :class:`HandDrawerTester`: dict images, inversion, one
    method call per scan, output copy. ``counts``: each tester's sCierres at the start."""
    machines = [HandDrawerTester(counts[i] if counts else 0) for i in range(n)]
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
            row: list[bool | int] = []
            for mach, _, outs in plan:
                row += [image_out[q] for q in outs]
                row += mach.fields()[4:]
            record.append(tuple(row))
    return time.perf_counter() - t0


def run_inline(n: int, cycles: int, events: Events, record: Record | None = None,
               counts: list[int] | None = None) -> float:
    """Seconds for the run as one inline loop: list images (inputs raw, the NC stop
    inverted where it is read), the state in lists, no call per tester. ``counts``: each
    tester's sCierres at the start."""
    image_in = [0] * (4 * n)
    image_out = [False] * (4 * n)
    state = [PARADO] * n
    t_enter = [0] * n
    s_paro = [False] * n
    s_cierres = list(counts) if counts else [0] * n
    prev_marcha = [False] * n
    bases = [(i, 4 * i) for i in range(n)]
    todo = [(k, [(point_index(p), v) for p, v in row]) for k, row in events]
    ten_s, limit = TEN_S, LIMIT
    ev, n_ev = 0, len(todo)
    t0 = time.perf_counter()
    for k in range(cycles):
        while ev < n_ev and todo[ev][0] <= k:
            for p, v in todo[ev][1]:
                image_in[p] = v
            ev += 1
        now = up = k * CYCLE_NS
        if k == 0:  # start-up: gsParado activated, its P1 clears sParo, nothing fires
            for i, b in bases:
                t_enter[i] = now
                s_paro[i] = False
                prev_marcha[i] = image_in[b + 1] != 0
                st = state[i]
                image_out[b] = st == ABRIR
                image_out[b + 1] = st == CERRAR
                image_out[b + 2] = st == PARADO or st == AVERIA and up % 500_000_000 < 250_000_000
                image_out[b + 3] = st == ABRIR or st == CERRAR
        else:
            for i, b in bases:
                paro = image_in[b] == 0
                marcha = image_in[b + 1] != 0
                sp = paro or s_paro[i]
                st = new = state[i]
                if st == PARADO:
                    if marcha and not prev_marcha[i] and not paro:
                        new = ABRIR
                elif st == ABRIR:
                    if image_in[b + 2]:
                        new = CERRAR
                    elif now - t_enter[i] >= ten_s:
                        new = AVERIA
                elif st == CERRAR:
                    if image_in[b + 3]:
                        new = PARADO if sp or s_cierres[i] >= limit else ABRIR
                    elif now - t_enter[i] >= ten_s:
                        new = AVERIA
                elif paro:
                    new = PARADO
                prev_marcha[i] = marcha
                if new != st:
                    state[i] = new
                    t_enter[i] = now
                    if st == PARADO:  # leaving gsParado (P0)
                        sp = False
                        if s_cierres[i] >= limit:
                            s_cierres[i] = 0
                    elif new == PARADO:  # entering it (P1)
                        sp = False
                    if new == CERRAR:  # a closing stroke starts
                        s_cierres[i] += 1
                    elif st == CERRAR and not image_in[b + 3]:  # cut by a failure
                        s_cierres[i] -= 1
                s_paro[i] = sp
                image_out[b] = new == ABRIR
                image_out[b + 1] = new == CERRAR
                image_out[b + 2] = (new == PARADO or sp and up % 1_000_000_000 < 500_000_000
                                    or new == AVERIA and up % 500_000_000 < 250_000_000)
                image_out[b + 3] = new == ABRIR or new == CERRAR
        if record is not None:
            row: list[bool | int] = []
            for i, b in bases:
                st = state[i]
                row += image_out[b:b + 4]
                row += [st == PARADO, st == ABRIR, st == CERRAR, st == AVERIA, s_paro[i],
                        s_cierres[i]]
            record.append(tuple(row))
    return time.perf_counter() - t0
