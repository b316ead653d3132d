"""``softplc simulate``: a plant on a virtual clock with simulated I/O, driven by a script.

Scan k happens at t = k·cycle; a scripted change at time t is seen by the first scan with
time >= t; nothing sleeps. The trace has one JSON object per scan (semantics.md), and a
last one naming the fault when a scan raises.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from drivers.sim import SimDriver
from runtime.compiler.evolution import UnstableChart
from runtime.engine.plant import Plant
from runtime.engine.script import Change, Event, bind, load_script
from runtime.engine.trace import (
    driver_columns,
    fault_row,
    trace_columns,
    write_trace,
    write_vcd,
)
from runtime.errors import Loc, SourceError
from runtime.language.model import PlantDef
from runtime.language.plantfile import load_plant

#: the script and trace functions, also imported from here by older callers
__all__ = ["Event", "ScanFault", "Simulation", "load_script", "trace_columns", "write_trace",
           "write_vcd"]


class Simulation:
    """A plant on a virtual clock; iterate ``run()`` to get one trace row per scan."""

    def __init__(self, plant_path: str, script_path: str | None = None,
                 cycles: int | None = None, *, pdef: PlantDef | None = None,
                 changes: list[Change] | None = None, coverage: bool = False) -> None:
        """``pdef``: the plant at ``plant_path``, already loaded; ``changes``: input
        changes already read (a scenario's), in place of a script; ``coverage``: the
        charts count what they do (``Program.coverage``)."""
        self.pdef = load_plant(plant_path) if pdef is None else pdef
        self.plant = Plant(self.pdef, sim=True, virtual=True, coverage=coverage)
        for d in self.plant.drivers.values():
            assert isinstance(d, SimDriver)
        duration: int | None = None
        script_cycles: int | None = None
        self.events: list[Event] = bind(self.plant, changes or [])
        if script_path is not None:
            duration, script_cycles, self.events = load_script(script_path, self.plant)
        if cycles is None and script_path is not None and (duration, script_cycles) == (
                None, None):
            raise SourceError(Loc(script_path, 1, 1), "the script needs 'duration:' or "
                                                      "'cycles:' (or give --cycles N)")
        cyc = self.plant.cycle_ns
        if cycles is not None:
            self.cycles = cycles
        elif script_cycles is not None:
            self.cycles = script_cycles
        elif duration is not None:
            self.cycles = -(-duration // cyc)  # scans at t = k·cycle while t < duration
        else:
            self.cycles = 100
        self.columns = trace_columns(self.plant)
        self.points = driver_columns(self.plant)

    def run(self, trace: bool = True) -> Iterator[dict[str, Any]]:
        """Run every scan; yields each scan's trace row (or nothing when ``trace`` is off:
        then the cycles between two scripted changes run in one call, ``Plant.cycles``).

        A scan that raises puts the plant in its safe state, yields a last row naming the
        fault (:func:`~runtime.engine.trace.fault_row`) and raises :class:`ScanFault`."""
        plant, events, cyc = self.plant, self.events, self.plant.cycle_ns
        plant.open()
        ev = 0
        n_ev = len(events)
        due = [-(-e.at_ns // cyc) for e in events]  # the first scan at or after each
        cols = self.columns
        k = 0
        while k < self.cycles:
            while ev < n_ev and due[ev] <= k:
                events[ev].apply()
                ev += 1
            stop = k + 1  # with a trace, cycle by cycle; without, up to the next change
            if not trace:
                stop = min(due[ev], self.cycles) if ev < n_ev else self.cycles
            t = k * cyc
            try:
                if trace:
                    plant.cycle(t)
                else:
                    plant.cycles(range(t, stop * cyc, cyc))
            except Exception as exc:  # a fault in a scan: outputs off, one clear line
                plant.safe_state()
                if not trace:  # the cycle that raised
                    t = plant.last_now
                    k = t // cyc
                fault, name = self._fault(exc, k, t)
                if trace:
                    yield fault_row(k, t, fault.message, name, self.points)
                raise fault from None
            if trace:
                row: dict[str, Any] = {"cycle": k, "t_ms": t // 1_000_000}
                for key, get in cols:
                    row[key] = get()
                yield row
            k = stop
        plant.safe_state()

    def _fault(self, exc: Exception, k: int, t: int) -> tuple[ScanFault, str | None]:
        """ScanFault at the instance whose scan raised ``exc`` (found by its state list in
        the traceback), or at the plant file; and that instance's name (None if none)."""
        name = None
        tb = exc.__traceback__
        while tb is not None:
            frame = tb.tb_frame
            if frame.f_code.co_filename.startswith("<grafcet "):
                m = frame.f_locals.get("m")
                name = next((n for n, i in self.plant.instances.items() if i.m is m), name)
            else:  # a scan inlined in the plant's cycle
                name = self.plant.instance_at(frame, tb.tb_lineno) or name
            tb = tb.tb_next
        what = str(exc) if isinstance(exc, UnstableChart) else f"{type(exc).__name__}: {exc}"
        if name is None:
            return ScanFault(self.pdef.instances[next(iter(self.pdef.instances))].loc
                             if self.pdef.instances else Loc(self.pdef.path, 1, 1),
                             f"expected every scan to end normally, found a fault in cycle "
                             f"{k} (t = {t // 1_000_000} ms): {what}"), None
        g = self.plant.instances[name].grafcet
        return ScanFault(self.pdef.instances[name].loc,
                         f"expected every scan to end normally, found a fault in the scan of "
                         f"instance '{name}' (grafcet {g.name}, {g.path}) in cycle {k} "
                         f"(t = {t // 1_000_000} ms): {what}"), name


class ScanFault(SourceError):
    """A scan of a simulated plant raised (unstable chart, division by zero ...): reported
    as one line at the instance in the plant file, never as a traceback."""


