"""``softplc simulate``: a plant on a virtual clock with simulated I/O, driven by a script.

Scan k happens at t = k·cycle; a scripted change at time t is seen by the first scan with
time >= t; nothing sleeps. The trace has one JSON object per scan (language.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import IO, Any

from drivers.base import Driver
from drivers.sim import SimDriver
from runtime.compiler.codegen import UnstableChart
from runtime.engine.instance import Instance, coerce
from runtime.engine.plant import Plant
from runtime.errors import Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.model import VarKind
from runtime.language.plantfile import load_plant
from runtime.language.typecheck import FB_MEMBERS
from runtime.language.yamlsrc import YList, YMap, load_yaml

T = A.Type


@dataclass
class Event:
    at_ns: int
    key: str
    value: Any
    apply: Callable[[], None]


def load_script(path: str, plant: Plant) -> tuple[int | None, int | None, list[Event]]:
    """Returns (duration_ns, cycles, events sorted by time, file order kept at equal times)."""
    doc = load_yaml(path)
    if not isinstance(doc, YMap):
        raise SourceError(Loc(path, 1, 1), "expected a mapping with 'duration:' or 'cycles:'")
    check_keys(doc, ("duration", "cycles", "set", "description"), "a simulation script")
    duration = cycles = None
    if "duration" in doc:
        duration = time_value(doc["duration"], doc.val_locs["duration"], "duration")
    if "cycles" in doc:
        cycles = expect_type(doc["cycles"], doc.val_locs["cycles"], int, "a number of cycles")
    if duration is None and cycles is None:
        raise SourceError(doc.loc, "the script needs 'duration:' or 'cycles:'")
    events: list[Event] = []
    items = doc.get("set") or YList()
    if items:
        expect_type(items, doc.val_locs["set"], YList, "a list of {at: TIME, name: value}")
    for item, loc in zip(items, getattr(items, "locs", []), strict=True):
        item = expect_type(item, loc, YMap, "{at: TIME, instance.input: value, ...}")
        if "at" not in item:
            raise SourceError(item.loc, "a 'set' entry needs 'at: TIME'")
        at = time_value(item["at"], item.val_locs["at"], "at")
        for key, value in item.items():
            if key == "at":
                continue
            events.append(_event(plant, at, key, value, item.key_locs[key], item.val_locs[key]))
    events.sort(key=lambda e: e.at_ns)
    return duration, cycles, events


def _event(plant: Plant, at: int, key: str, value: Any, kloc: Loc, vloc: Loc) -> Event:
    head, _, rest = key.partition(".")
    if head in plant.instances and rest:
        inst = plant.instances[head]
        g = inst.grafcet
        var = g.variables.get(rest)
        idef = plant.pdef.instances[head]
        if var is None or (var.kind is not VarKind.INPUT and var.kind is not VarKind.FLAG):
            names = [v.name for v in g.variables.values() if v.kind in (VarKind.INPUT,
                                                                          VarKind.FLAG)]
            raise SourceError(kloc, f"'{key}' is not an input or chart flag of {head}"
                                    f"{suggest(rest, names)}")
        try:
            logical = coerce(var.type, value)
        except ValueError as exc:
            raise SourceError(vloc, f"bad value for '{key}': {exc}") from None
        b = idef.inputs.get(rest)
        if b is None:  # an unbound chart flag: written into the instance
            def apply() -> None:
                inst.set(rest, logical)
            return Event(at, key, logical, apply)
        if b.driver is None or b.point == "ok":
            raise SourceError(kloc, f"'{key}' is bound to '{b.source}': drive that instead")
        drv = plant.drivers[b.driver]
        point = b.point or ""
        phys = (not logical if b.invert else logical) if var.type is T.BOOL else logical
        phys_v = int(phys) if isinstance(phys, bool) else phys

        def apply_point() -> None:
            drv.inputs[point] = phys_v
        return Event(at, key, logical, apply_point)
    if head in plant.drivers and rest:
        drv = plant.drivers[head]
        if rest not in drv.inputs:
            raise SourceError(kloc, f"'{key}' is not an input point of driver {head}"
                                    f"{suggest(rest, drv.inputs)}")
        if isinstance(value, bool):
            value = int(value)
        if not isinstance(value, int | float):
            raise SourceError(vloc, f"expected a number for '{key}', found {value!r}")

        def apply_raw() -> None:
            drv.inputs[rest] = value
        return Event(at, key, value, apply_raw)
    raise SourceError(kloc, f"unknown name '{key}': expected instance.input, instance.SFCFlag "
                            "or driver.point" + suggest(head, [*plant.instances,
                                                               *plant.drivers]))


def trace_columns(plant: Plant) -> list[tuple[str, Callable[[], Any]]]:
    """(key, getter) for every traced value, as language.md lists them."""
    cols: list[tuple[str, Callable[[], Any]]] = []
    for name, inst in plant.instances.items():
        g, m, prog = inst.grafcet, inst.m, inst.program
        for v in g.variables.values():
            if v.kind is VarKind.SYSTEM:
                continue
            if v.name == "SFCCurrentStep":
                cols.append((f"{name}.SFCCurrentStep", inst.current_step))
                continue
            i = prog.var_index(v.name)
            kind = "bool" if v.type is T.BOOL else "ms" if v.type is T.TIME else "raw"
            cols.append((f"{name}.{v.name}", _slot(m, i, kind)))
        for s in g.steps:
            cols.append((f"{name}.{s}.X", _slot(m, prog.x_index(s), "bool")))
            cols.append((f"{name}.{s}.T_ms", _step_ms(inst, s)))
        for b in g.blocks.values():  # extra keys: function-block outputs (ET in ms)
            for member, (mtype, is_input) in FB_MEMBERS[b.kind].items():
                if not is_input:
                    cols.append((f"{name}.{b.name}.{member}",
                                 _member(m, prog.block_index(b.name), member, mtype)))
    for dname, d in plant.drivers.items():
        for p in d.inputs:
            cols.append((f"{dname}.{p}", _point(d.inputs, p)))
        for p in d.outputs:
            cols.append((f"{dname}.{p}", _point(d.outputs, p)))
        cols.append((f"{dname}.ok", _driver_ok(d)))
    return cols


def _slot(m: list[Any], i: int, kind: str) -> Callable[[], Any]:
    """Getter of state slot ``i``: a bool as 0/1, a time (ns) as whole ms, else as is."""
    if kind == "bool":
        return lambda: 1 if m[i] else 0
    if kind == "ms":
        return lambda: m[i] // 1_000_000
    return lambda: m[i]


def _member(m: list[Any], i: int, member: str, mtype: A.Type) -> Callable[[], Any]:
    """Getter of a function block's output: bools as 0/1, times in whole ms."""
    if mtype is T.BOOL:
        return lambda: 1 if getattr(m[i], member) else 0
    if mtype is T.TIME:
        return lambda: getattr(m[i], member) // 1_000_000
    return lambda: getattr(m[i], member)


def _step_ms(inst: Instance, step: str) -> Callable[[], int]:
    return lambda: inst.step_time(step) // 1_000_000


def _point(image: dict[str, Any], point: str) -> Callable[[], Any]:
    return lambda: _num(image[point])


def _driver_ok(d: Driver) -> Callable[[], int]:
    return lambda: 1 if d.ok else 0


def _num(v: Any) -> Any:
    return int(v) if isinstance(v, bool) else v


class Simulation:
    """A plant on a virtual clock; iterate ``run()`` to get one trace row per scan."""

    def __init__(self, plant_path: str, script_path: str | None = None,
                 cycles: int | None = None) -> None:
        self.pdef = load_plant(plant_path)
        self.plant = Plant(self.pdef, sim=True, virtual=True)
        for d in self.plant.drivers.values():
            assert isinstance(d, SimDriver)
        duration: int | None = None
        script_cycles: int | None = None
        self.events: list[Event] = []
        if script_path is not None:
            duration, script_cycles, self.events = load_script(script_path, self.plant)
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

    def run(self, trace: bool = True) -> Iterator[dict[str, Any]]:
        """Run every scan; yields each scan's trace row (or nothing when ``trace`` is off)."""
        plant, events, cyc = self.plant, self.events, self.plant.cycle_ns
        plant.open()
        ev = 0
        n_ev = len(events)
        cols = self.columns
        for k in range(self.cycles):
            t = k * cyc
            while ev < n_ev and events[ev].at_ns <= t:
                events[ev].apply()
                ev += 1
            try:
                plant.cycle(t)
            except Exception as exc:  # a fault in a scan: outputs off, one clear line
                plant.safe_state()
                raise self._fault(exc, k, t) from None
            if trace:
                row: dict[str, Any] = {"cycle": k, "t_ms": t // 1_000_000}
                for key, get in cols:
                    row[key] = get()
                yield row
        plant.safe_state()


    def _fault(self, exc: Exception, k: int, t: int) -> ScanFault:
        """ScanFault at the instance whose scan raised ``exc`` (found by its state list in
        the traceback), or at the plant file."""
        name = None
        tb = exc.__traceback__
        while tb is not None:
            frame = tb.tb_frame
            if frame.f_code.co_filename.startswith("<grafcet "):
                m = frame.f_locals.get("m")
                name = next((n for n, i in self.plant.instances.items() if i.m is m), name)
            tb = tb.tb_next
        what = str(exc) if isinstance(exc, UnstableChart) else f"{type(exc).__name__}: {exc}"
        if name is None:
            return ScanFault(self.pdef.instances[next(iter(self.pdef.instances))].loc
                             if self.pdef.instances else Loc(self.pdef.path, 1, 1),
                             f"expected every scan to end normally, found a fault in cycle "
                             f"{k} (t = {t // 1_000_000} ms): {what}")
        g = self.plant.instances[name].grafcet
        return ScanFault(self.pdef.instances[name].loc,
                         f"expected every scan to end normally, found a fault in the scan of "
                         f"instance '{name}' (grafcet {g.name}, {g.path}) in cycle {k} "
                         f"(t = {t // 1_000_000} ms): {what}")


class ScanFault(SourceError):
    """A scan of a simulated plant raised (unstable chart, division by zero ...): reported
    as one line at the instance in the plant file, never as a traceback."""


def write_trace(rows: Iterator[dict[str, Any]], out: IO[str]) -> int:
    n = 0
    for row in rows:
        out.write(json.dumps(row, ensure_ascii=False, separators=(",", ":")))
        out.write("\n")
        n += 1
    return n


def write_vcd(rows: list[dict[str, Any]], out: IO[str]) -> None:
    """Value Change Dump of a trace (GTKWave, Surfer): one signal per traced key, in ms."""
    if not rows:
        return
    keys = [k for k in rows[0] if k not in ("cycle", "t_ms")]
    kinds: dict[str, str] = {}
    for k in keys:
        values = {r[k] for r in rows}
        if any(isinstance(v, str) for v in values):
            kinds[k] = "string"
        elif any(isinstance(v, float) for v in values):
            kinds[k] = "real"
        elif values <= {0, 1}:
            kinds[k] = "wire"
        else:
            kinds[k] = "integer"
    ids = {}
    for i, k in enumerate(keys):
        code, n = "", i
        while True:
            code += chr(33 + n % 94)
            n //= 94
            if not n:
                break
        ids[k] = code
    decl = {"wire": "wire 1", "integer": "integer 64", "real": "real 64", "string": "string 1"}
    out.write("$timescale 1ms $end\n$scope module softplc $end\n")
    for k in keys:
        out.write(f"$var {decl[kinds[k]]} {ids[k]} {k} $end\n")
    out.write("$upscope $end\n$enddefinitions $end\n")
    last: dict[str, Any] = {}
    for r in rows:
        changes = [k for k in keys if k not in last or last[k] != r[k]]
        if not changes:
            continue
        out.write(f"#{r['t_ms']}\n")
        for k in changes:
            v, kind, code = r[k], kinds[k], ids[k]
            if kind == "wire":
                out.write(f"{int(v)}{code}\n")
            elif kind == "real":
                out.write(f"r{v} {code}\n")
            elif kind == "string":
                out.write(f"s{str(v).replace(' ', '_') or '-'} {code}\n")
            else:
                iv = int(v)
                out.write(f"b{iv & 0xFFFFFFFFFFFFFFFF:b} {code}\n")
            last[k] = v
