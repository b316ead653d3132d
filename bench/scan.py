"""Benchmark: the compiled engine against the same chart hand-written in Python.

Measures, for 1, 10, 100 and 1000 instances of the drawer tester of
``configs/drawer_tester/drawer_tester.yaml`` (seed 000, the complete chart), the loop time
of four runs of the same simulated plant on the same scripted input story:

- compiled: the whole ``softplc simulate`` run without a trace (``Simulation.run``): script
  events written into the sim driver's image, the plant cycle with its process image,
  inverted bindings and output copy, and the generated scan of every instance; the cycles
  between two scripted changes run in one ``Plant.cycles`` call;
- ``cycle()`` (``run_per_cycle``): the same with one ``Plant.cycle`` call per cycle, as
  the daemon and a traced simulation call it (the plant's bookkeeping once per cycle);
- inline (``bench.handwritten.run_inline``): the chart hand-written as an ordinary inline
  Python loop over the instances: no call per instance, state in lists, the process image
  as plain lists indexed by integers;
- hand (``bench.handwritten.run_hand``): the chart as an idiomatic state-machine class,
  one method call per instance, string-keyed dict images like the compiled plant's.

Before timing, both hand-written runs are checked against the compiled plant cycle by cycle
(:func:`check_baselines`): every output, step flag and memory of every tester equal at every
cycle, over two periods of the input pattern (start, strokes, stop at end of cycle, failure
by time while opening and while closing, acknowledge, restart), half the testers starting
three closes short of the end of the test so that it ends and restarts too. Runs alternate
(compiled, ``cycle()``, inline, hand, repeated) so all see the same machine load; the best of
``--repeat`` is kept. Also times the compilation of the chart (load, check and compile, in
process). Not a test: prints a table.

The plant of 1000 testers (about 300 kB, 20 000 YAML nodes) loads as ``softplc`` loads it,
within the file limits of ``runtime.language.yamlsrc`` (1 MiB; 10 000 nodes plus a quarter
of the size).

    python -m bench.scan [--counts 1 10 100 1000] [--cycles N] [--repeat 5]

The whole-process comparison (``softplc simulate`` against the inline loop, each a fresh
Python process, timed with ``time``): ``--write DIR`` writes the plant and script of
``--counts N`` testers (the script's input story over ``--story`` cycles: a script file is
limited to 1 MiB) and exits; ``--inline-process`` runs the inline loop once on the same
story and exits:

    python -m bench.scan --write /tmp/sim --counts 100 --story 36000
    time softplc simulate /tmp/sim/plant.yaml --script /tmp/sim/script.yaml --cycles 100000
    time python -m bench.scan --inline-process --counts 100 --cycles 100000 --story 36000

``--startup`` measures the daemon's start-up to READY for ``--counts N`` testers: ``softplc
run`` of the plant (sim drivers, with a retain file) started ``--repeat`` times, the time
from the process start to the ``READY=1`` datagram on its ``$NOTIFY_SOCKET``:

    python -m bench.scan --startup --counts 100 --repeat 5
"""

from __future__ import annotations

import argparse
import gc
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable

from bench.handwritten import (
    FIELDS,
    LIMIT,
    Events,
    Record,
    points,
    run_hand,
    run_inline,
)
from runtime.compiler.codegen import compile_grafcet
from runtime.engine.simulate import Simulation
from runtime.language.grafcetfile import GrafcetLoader
from runtime.language.yamlsrc import YMap, load_yaml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHART = os.path.join(ROOT, "configs", "drawer_tester", "drawer_tester.yaml")
#: a hand-written run: (n, cycles, events, record, counts) -> seconds
Baseline = Callable[[int, int, Events, Record | None, list[int] | None], float]
BASELINES: dict[str, Baseline] = {"inline": run_inline, "hand": run_hand}


def out(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


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


def changes(n: int, cycles: int) -> Events:
    """(cycle, [(point, value)]) where some instance's physical inputs change."""
    last: list[tuple[int, ...] | None] = [None] * n
    out_: Events = []
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


def simulation(ppath: str, spath: str) -> Simulation:
    """The ``softplc simulate`` run of plant ``ppath`` and script ``spath``, built."""
    return Simulation(ppath, spath)


def run_compiled(ppath: str, spath: str) -> float:
    """Seconds for the whole ``simulate`` run without a trace (the loop, not the load)."""
    sim = simulation(ppath, spath)
    gc.collect()  # the load's garbage is not the loop's cost
    t0 = time.perf_counter()
    for _ in sim.run(trace=False):
        pass
    return time.perf_counter() - t0


def run_per_cycle(ppath: str, spath: str) -> float:
    """Seconds for the same run with one ``Plant.cycle`` call per cycle (the loop of a
    traced simulation, without its rows)."""
    sim = simulation(ppath, spath)
    plant, events, cyc = sim.plant, sim.events, sim.plant.cycle_ns
    plant.open()
    due = [-(-e.at_ns // cyc) for e in events]
    ev, n_ev = 0, len(events)
    cycle = plant.cycle
    gc.collect()
    t0 = time.perf_counter()
    for k in range(sim.cycles):
        while ev < n_ev and due[ev] <= k:
            events[ev].apply()
            ev += 1
        cycle(k * cyc)
    return time.perf_counter() - t0


def check_counts(n: int) -> list[int]:
    """sCierres of each tester at the start of the check: every other one three closes
    short of the end of the test, so the check sees a test end and a new one begin."""
    return [LIMIT - 3 if i % 2 else 0 for i in range(n)]


def compiled_record(ppath: str, spath: str, n: int, counts: list[int]) -> Record:
    """The compiled plant's :data:`~bench.handwritten.FIELDS` of every tester, every cycle
    (outputs read in the sim driver's image, the rest in the trace)."""
    sim = simulation(ppath, spath)
    for i, c in enumerate(counts):
        sim.plant.set(f"t{i}.sCierres", c)
    keys = []
    for i in range(n):
        keys += [f"sim.{q}" for q in points(i)[1]]
        keys += [f"t{i}.{f}" for f in FIELDS[4:]]
    wanted = set(keys)
    sim.columns = [c for c in sim.columns if c[0] in wanted]
    counted = {k for k in keys if k.endswith(".sCierres")}  # the one number: as it is
    return [tuple(row[k] if k in counted else bool(row[k]) for k in keys)
            for row in sim.run(trace=True)]


def divergence(want: Record, got: Record) -> str | None:
    """The first difference of ``got`` from ``want`` in words, or None if equal."""
    if len(want) != len(got):
        return f"{len(got)} cycles recorded, {len(want)} expected"
    width = len(FIELDS)
    for k, (a, b) in enumerate(zip(want, got, strict=True)):
        if a != b:
            j = next(j for j, (x, y) in enumerate(zip(a, b, strict=True)) if x != y)
            return (f"cycle {k}, tester t{j // width}, {FIELDS[j % width]}: compiled "
                    f"{a[j]!r}, hand-written {b[j]!r}")
    return None


def check_baselines(d: str, n: int, cycles: int,
                    baselines: dict[str, Baseline] | None = None) -> dict[str, str]:
    """Run the compiled plant and every baseline (default :data:`BASELINES`) with ``n``
    testers for ``cycles`` cycles in directory ``d``; the baselines that diverge, with
    their first difference (empty: all agree at every cycle)."""
    counts = check_counts(n)
    ppath, spath = write_files(d, n, cycles)
    want = compiled_record(ppath, spath, n, counts)
    events = changes(n, cycles)
    found = {}
    for name, run in (baselines or BASELINES).items():
        got: Record = []
        run(n, cycles, events, got, counts)
        why = divergence(want, got)
        if why is not None:
            found[name] = why
    return found


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


def ready_time(plant: str, notify: str) -> float:
    """Seconds from starting ``softplc run plant`` to its READY=1 on ``notify``."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind(notify)
        sock.settimeout(30)
        env = {**os.environ, "NOTIFY_SOCKET": notify, "PYTHONPATH": ROOT}
        env.pop("JOURNAL_STREAM", None)
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "runtime.cli", "run", plant],
                                cwd=os.path.dirname(plant), env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            while not sock.recv(4096).startswith(b"READY=1"):
                pass
            took = time.perf_counter() - t0
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
        os.unlink(notify)
    return took


def startup(n: int, repeat: int) -> int:
    """Print the start-up to READY of ``n`` testers, ``repeat`` runs."""
    with tempfile.TemporaryDirectory() as d:
        ppath, _ = write_files(d, n, 1)
        with open(ppath, encoding="utf-8") as f:
            text = f.read()
        with open(ppath, "w", encoding="utf-8") as f:
            f.write(text.replace("plc: {cycle: 10ms, watchdog: 100ms}",
                                 f"plc: {{cycle: 10ms, watchdog: 100ms, "
                                 f"retain: {d}/retain.json}}"))
        times = [ready_time(ppath, os.path.join(d, "notify.sock")) for _ in range(repeat)]
    out(f"start-up to READY=1, {n} testers, {repeat} runs: min {min(times):.3f} s, "
        f"median {statistics.median(times):.3f} s, max {max(times):.3f} s")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--cycles", type=int, default=0, help="cycles per run (default: scaled)")
    ap.add_argument("--counts", type=int, nargs="+", default=[1, 10, 100, 1000])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--write", metavar="DIR", help="write plant.yaml and script.yaml, exit")
    ap.add_argument("--inline-process", action="store_true",
                    help="run the inline loop once (for `time`), exit")
    ap.add_argument("--startup", action="store_true",
                    help="time `softplc run` of the plant from start to READY=1, exit")
    ap.add_argument("--story", type=int, default=36000,
                    help="cycles of input story for --write / --inline-process")
    args = ap.parse_args()
    if args.write:
        out(" ".join(write_files(args.write, args.counts[0], args.story)))
        return 0
    if args.startup:
        return startup(args.counts[0], args.repeat)
    if args.inline_process:
        n = args.counts[0]
        run_inline(n, args.cycles or 100_000, changes(n, args.story), None, None)
        return 0
    ct = compile_times(20)
    out(f"compile {os.path.relpath(CHART, ROOT)} (load + check + compile, in process, 20 runs): "
        f"min {min(ct) * 1e3:.1f} ms, median {statistics.median(ct) * 1e3:.1f} ms")
    out(f"Python {sys.version.split()[0]}; best of {args.repeat} alternating runs, loop time")
    out(f"{'instances':>9} {'cycles':>7} {'compiled ns':>11} {'cycle() ns':>10} {'inline ns':>9} "
        f"{'hand ns':>8} {'vs inline':>9} {'cycle() vs inline':>17} {'vs hand':>7} "
        f"{'ms/cycle':>9}")
    with tempfile.TemporaryDirectory() as d:
        for n in args.counts:
            cycles = args.cycles or max(500, 200_000 // n)
            # equivalence over two periods of the pattern (testers are independent: 100
            # of them, at 100 phases of the pattern, are enough)
            bad = check_baselines(d, min(n, 100), 2 * PERIOD + 300)
            for name, why in bad.items():
                out(f"MISMATCH of the {name} baseline with {min(n, 100)} testers: {why}")
            if bad:
                return 1
            ppath, spath = write_files(d, n, cycles)
            events = changes(n, cycles)
            runs: dict[str, list[float]] = {"compiled": [], "cycle()": [], "inline": [],
                                             "hand": []}
            for _ in range(args.repeat):  # alternating: all see the same machine load
                for name in runs:  # the garbage of the last run is not this one's cost
                    gc.collect()
                    runs[name].append(
                        run_compiled(ppath, spath) if name == "compiled"
                        else run_per_cycle(ppath, spath) if name == "cycle()"
                        else BASELINES[name](n, cycles, events, None, None))
            t_c, t_p, t_i, t_h = (min(v) for v in runs.values())
            scans = n * cycles
            out(f"{n:>9} {cycles:>7} {t_c / scans * 1e9:>11.0f} {t_p / scans * 1e9:>10.0f} "
                f"{t_i / scans * 1e9:>9.0f} {t_h / scans * 1e9:>8.0f} {t_c / t_i:>9.2f} "
                f"{t_p / t_i:>17.2f} {t_c / t_h:>7.2f} {t_c / cycles * 1e3:>9.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
