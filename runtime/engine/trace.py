"""The trace of a plant: one row of values per cycle (language.md), as JSON lines or VCD.

Used by ``softplc simulate`` and by ``softplc run --trace``: the columns are read from the
plant's process image through the compiled programs' accessors.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from typing import IO, Any

from drivers.base import Driver
from drivers.image import Image
from runtime.compiler.program import Memory
from runtime.engine.instance import Instance
from runtime.engine.plant import Plant
from runtime.language import ast as A
from runtime.language.model import VarKind
from runtime.language.signatures import FB_MEMBERS

T = A.Type


def trace_columns(plant: Plant) -> list[tuple[str, Callable[[], Any]]]:
    """(key, getter) for every traced value, as semantics.md lists them: the instances'
    values, then the drivers' (:func:`driver_columns`)."""
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
    return cols + driver_columns(plant)


def driver_columns(plant: Plant) -> list[tuple[str, Callable[[], Any]]]:
    """(key, getter) for every driver point (the process image) and every ``driver.ok``."""
    cols: list[tuple[str, Callable[[], Any]]] = []
    for dname, d in plant.drivers.items():
        for p, i in d.inputs.index.items():
            cols.append((f"{dname}.{p}", _point(d.inputs, i)))
        for p, i in d.outputs.index.items():
            cols.append((f"{dname}.{p}", _point(d.outputs, i)))
        cols.append((f"{dname}.ok", _driver_ok(d)))
    return cols


def _slot(m: Memory, i: int, kind: str) -> Callable[[], Any]:
    """Getter of state slot ``i``: a bool as 0/1, a time (ns) as whole ms, else as is."""
    if kind == "bool":
        return lambda: 1 if m[i] else 0
    if kind == "ms":
        return lambda: m[i] // 1_000_000
    return lambda: m[i]


def _member(m: Memory, i: int, member: str, mtype: A.Type) -> Callable[[], Any]:
    """Getter of a function block's output: bools as 0/1, times in whole ms."""
    if mtype is T.BOOL:
        return lambda: 1 if getattr(m[i], member) else 0
    if mtype is T.TIME:
        return lambda: getattr(m[i], member) // 1_000_000
    return lambda: getattr(m[i], member)


def _step_ms(inst: Instance, step: str) -> Callable[[], int]:
    return lambda: inst.step_time(step) // 1_000_000


def _point(image: Image, pos: int) -> Callable[[], Any]:
    """Getter of the point at position ``pos`` of a driver's image (its value list)."""
    vals = image.vals
    return lambda: _num(vals[pos])


def _driver_ok(d: Driver) -> Callable[[], int]:
    return lambda: 1 if d.ok else 0


def _num(v: Any) -> Any:
    return int(v) if isinstance(v, bool) else v


def fault_row(k: int, t_ns: int, fault: str, instance: str | None,
              points: list[tuple[str, Callable[[], Any]]]) -> dict[str, Any]:
    """The last record of a trace whose scan ``k`` (at ``t_ns``) faulted: the fault's
    message, the instance whose scan raised (None if none), and the process image after
    the safe state (``points``: :func:`driver_columns`). The instances' values are left
    out: the scan that raised left them half-computed."""
    row: dict[str, Any] = {"cycle": k, "t_ms": t_ns // 1_000_000, "fault": fault,
                           "instance": instance}
    for key, get in points:
        row[key] = get()
    return row


def write_trace(rows: Iterator[dict[str, Any]], out: IO[str]) -> int:
    """One JSON line per row, written as the rows come (a run that stops on a fault keeps
    every row before it); returns the number of rows."""
    n = 0
    for row in rows:
        out.write(json.dumps(row, ensure_ascii=False, separators=(",", ":")))
        out.write("\n")
        n += 1
    return n


def write_vcd(rows: list[dict[str, Any]], out: IO[str]) -> None:
    """Value Change Dump of a trace (GTKWave, Surfer): one signal per traced key, in ms.
    A key missing from a row (the fault record has only the drivers' points) keeps its
    value; the fault record's ``fault`` is a string signal, ``-`` until the fault."""
    if not rows:
        return
    keys: list[str] = []
    for r in rows:
        keys += [k for k in r if k not in ("cycle", "t_ms", "instance") and k not in keys]
    if "fault" in keys:
        rows = [r if "fault" in r else {**r, "fault": ""} for r in rows]
    kinds: dict[str, str] = {}
    for k in keys:
        values = {r[k] for r in rows if k in r}
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
        changes = [k for k in keys if k in r and (k not in last or last[k] != r[k])]
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
