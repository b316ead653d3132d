"""``Plant.cycles``: a run of cycles in one call (simulate without a trace) is the same as
calling ``Plant.cycle`` at each time: the same state, scans, clock and outputs after every
stretch, whatever happens between stretches (pause, step, forces, pulses), the same fault
at the same cycle, and the same stop on a driver fault."""

from __future__ import annotations

import inspect
import os
import random
import sys
from collections.abc import Callable
from types import FrameType
from typing import Any

import pytest

from drivers.base import DriverError
from drivers.sim import SimDriver
from runtime.engine.plant import Plant
from runtime.engine.simulate import ScanFault, Simulation
from runtime.language.plantfile import load_plant

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
CHART = os.path.join(ROOT, "configs", "drawer_tester", "drawer_tester.yaml")
CYCLE = 10_000_000
N = 12  # drawer testers: more than one group of inlined scans (inline.NAMES)

Write = Callable[[str, str], str]


def plant_file(write: Write) -> str:
    """N drawer testers on one sim driver (``on_fault: stop``), tester i on I/O 4i..4i+3."""
    lines = ["plc: {cycle: 10ms}", "drivers: {sim: {type: sim, on_fault: stop}}",
             "instances:"]
    for i in range(N):
        lines += [f"  t{i}:", f"    grafcet: {CHART}", "    inputs:",
                  f"      iParo: {{from: sim.I{4 * i}, invert: true}}",
                  f"      iMarcha: sim.I{4 * i + 1}", f"      iAbierto: sim.I{4 * i + 2}",
                  f"      iCerrado: sim.I{4 * i + 3}", "    outputs:",
                  *(f"      {o}: sim.Q{4 * i + j}" for j, o in
                    enumerate(("oAbrir", "oCerrar", "oParado", "oTest")))]
    return write("plant.yaml", "\n".join(lines) + "\n")


def snapshot(plant: Plant) -> tuple[Any, ...]:
    sim = plant.drivers["sim"]
    assert isinstance(sim, SimDriver)
    return (plant.scans, plant.last_up, plant.start, plant.offset_ns, plant._last_scan,
            plant._stood_still, plant._usual, plant.steps_left, plant.hold,
            [list(i.m) for i in plant.instances.values()], dict(sim.outputs.items()),
            sim.written)


def twins(write: Write, virtual: bool) -> tuple[Plant, Plant]:
    path = plant_file(write)
    one, batch = (Plant(load_plant(path), sim=True, virtual=virtual) for _ in range(2))
    for p in (one, batch):
        p.open()
    return one, batch


def both_raise(exc: type[BaseException], one: Plant, batch: Plant, times: range) -> None:
    """``one`` cycle by cycle and ``batch`` in one run over ``times``: both raise ``exc``
    and end in the same state."""
    with pytest.raises(exc):
        for now in times:
            one.cycle(now)
    with pytest.raises(exc):
        batch.cycles(times)
    assert snapshot(batch) == snapshot(one)


def on_read(plant: Plant, monkeypatch: pytest.MonkeyPatch, n: int,
            act: Callable[[], None]) -> None:
    """``act()`` at the ``n``-th read of the plant's sim driver (counted from 0)."""
    reads = iter(range(10**6))
    real = plant.drivers["sim"]._read

    def read() -> None:
        if next(reads) == n:
            act()
        real()

    monkeypatch.setattr(plant.drivers["sim"], "_read", read)


@pytest.mark.parametrize("virtual", [True, False])
@pytest.mark.parametrize("t0", [0, 1_000_000_007])
def test_a_run_of_cycles_is_cycle_after_cycle(write: Write, virtual: bool, t0: int,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Random stretches of cycles with the inputs, the console and forces changed between
    them: a zero and a non-zero start, a virtual plant and one that calls its drivers."""
    one, batch = twins(write, virtual)
    called = []  # the batch's cycles run by ``cycle`` (the unusual ones)
    cycle = Plant.cycle

    def counted(self: Plant, now: int) -> str | None:
        if self is batch:
            called.append(now)
        return cycle(self, now)

    monkeypatch.setattr(Plant, "cycle", counted)
    rng = random.Random(t0 + virtual)
    ops: list[Callable[[Plant], object]] = [
        lambda p: None, lambda p: p.pause(), lambda p: p.step(3), lambda p: p.resume(),
        lambda p: p.force("t3.iMarcha", True), lambda p: p.unforce(None),
        lambda p: p.force("sim.Q5", 1), lambda p: p.pulse("t7", "SFCInit"),
        lambda p: p.instances["t1"].set("sCierres", 999)]
    t, total = t0, 0
    for _ in range(60):
        inputs = {f"I{rng.randrange(4 * N)}": rng.randrange(2) for _ in range(rng.randrange(6))}
        op = rng.choice(ops) if rng.random() < 0.3 else ops[0]
        back = rng.random() < 0.4  # running again, nothing forced
        length = rng.choice([1, 2, 7, 8, 40, 300])
        times = range(t, t + length * CYCLE, CYCLE)
        for p in (one, batch):
            p.drivers["sim"].inputs.update(inputs)
            if back:
                p.resume()
                p.unforce(None)
            op(p)
        for now in times:
            assert one.cycle(now) is None
        assert batch.cycles(times) is None
        assert snapshot(batch) == snapshot(one)
        t, total = times.stop, total + len(times)
    assert total - len(called) > 1000  # cycles run in the batch's own loop


DIVIDES = """\
grafcet: Count
inputs: [d]
memory: {c: 0, q: 0}
pre: ["c := c + 1", "q := 10 / (250 - c)"]
steps:
  s: {initial: true}
"""


@pytest.mark.parametrize("t0", [0, 1_000_000_007])
def test_a_fault_in_the_middle_of_a_run_is_the_same_as_cycle_by_cycle(write: Write,
                                                                      t0: int) -> None:
    """A scan that raises in the middle of a run (no scripted change there): the same
    fault, at the same cycle and time, and the same bookkeeping as one cycle at a time."""
    write("count.yaml", DIVIDES)
    path = write("p.yaml", "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\ninstances:\n"
                 + "".join(f"  c{k}: {{grafcet: count.yaml, inputs: {{d: sim.I{k}}}}}\n"
                         for k in range(N)))
    one, batch = (Plant(load_plant(path), sim=True, virtual=True) for _ in range(2))
    one.instances["c9"].set("c", 3)  # c9 raises first: in the scan of cycle 246
    batch.instances["c9"].set("c", 3)
    both_raise(ZeroDivisionError, one, batch, range(t0, t0 + 1000 * CYCLE, CYCLE))
    assert batch.scans == 246 and batch.last_up == 246 * CYCLE
    assert batch.last_now == t0 + 246 * CYCLE
    script = write("s.yaml", "cycles: 1000\nset:\n  - {at: 1ms, sim.I0: 1}\n")
    messages = []
    for trace in (True, False):
        sim = Simulation(path, script)
        sim.plant.instances["c9"].set("c", 3)
        with pytest.raises(ScanFault) as err:
            for _ in sim.run(trace=trace):
                pass
        messages.append(str(err.value))
    assert messages[0] == messages[1]
    assert "instance 'c9'" in messages[1] and "in cycle 246 (t = 2460 ms)" in messages[1]


@pytest.mark.parametrize("t0", [0, 1_000_000_007])
def test_a_driver_fault_stops_a_run_where_it_stops_a_cycle(
        write: Write, monkeypatch: pytest.MonkeyPatch, t0: int) -> None:
    """A driver whose policy is ``stop`` faults in the middle of a run: the run ends at
    that cycle with its reason, as ``cycle`` returns it, and nothing after it runs."""
    one, batch = (Plant(load_plant(plant_file(write)), sim=True) for _ in range(2))

    def gone() -> None:
        raise DriverError("bus gone")

    for p in (one, batch):
        p.open()
        on_read(p, monkeypatch, 57, gone)
    times = range(t0, t0 + 100 * CYCLE, CYCLE)
    why = next(filter(None, (one.cycle(now) for now in times)))
    assert batch.cycles(times) == why == "driver sim: bus gone"
    assert snapshot(batch) == snapshot(one)
    assert batch.scans == 57


def test_a_group_ended_in_the_middle_of_a_run_is_started_again_as_by_cycle(
        write: Write, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A group's generator ended by an exception outside its scans (closed here from the
    driver's read, between two cycles of a run): the run raises at that cycle as
    ``cycle`` does, the group is started again, and both go on alike."""
    one, batch = (Plant(load_plant(plant_file(write)), sim=True) for _ in range(2))
    for p in (one, batch):
        p.open()
        on_read(p, monkeypatch, 30, p._inliner._gens[1].close)
    times = range(0, 100 * CYCLE, CYCLE)
    both_raise(StopIteration, one, batch, times)
    assert batch.scans == 30 and caplog.text.count("started again") == 2
    later = range(times.stop, times.stop + 50 * CYCLE, CYCLE)
    for now in later:
        assert one.cycle(now) is None
    assert batch.cycles(later) is None
    assert snapshot(batch) == snapshot(one)


def test_a_ctrl_c_between_two_cycles_of_a_run_leaves_them_counted(write: Write) -> None:
    """A KeyboardInterrupt where a signal lands between two cycles of a run (the loop's
    back edge, raised here by a line tracer): the cycles before it count, as when it
    lands between two calls of ``cycle``."""
    one, batch = twins(write, virtual=True)
    lines, first = inspect.getsourcelines(Plant._usual_cycles)
    loops = {first + k for k, line in enumerate(lines) if "for pnow in program:" in line}
    seen = 0

    def tracer(frame: FrameType, event: str, arg: Any) -> Any:
        nonlocal seen
        if event == "line" and frame.f_lineno in loops:
            seen += 1
            if seen == 41:  # after 40 cycles
                raise KeyboardInterrupt
        return tracer

    def calls(frame: FrameType, event: str, arg: Any) -> Any:
        return tracer if frame.f_code is Plant._usual_cycles.__code__ else None

    for now in range(0, 3 * CYCLE, CYCLE):  # started: the next cycles are usual
        one.cycle(now)
        batch.cycle(now)
    times = range(3 * CYCLE, 100 * CYCLE, CYCLE)
    for now in times[:40]:
        one.cycle(now)
    was = sys.gettrace()
    sys.settrace(calls)
    try:
        with pytest.raises(KeyboardInterrupt):
            batch.cycles(times)
    finally:
        sys.settrace(was)
    assert len(loops) == 2 and seen == 41
    assert snapshot(batch) == snapshot(one) and batch.scans == 43
