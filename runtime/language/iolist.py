"""The I/O list of a plant: what each signal means to a person (docs/language.md, "The
I/O list"). One home for it, read by every part that shows a plant to people: the OPC UA
server (Description, EngineeringUnits, EURange, the point -> signal reference), the
console's ``get`` and ``why``, the monitor, ``softplc draw`` (its legend), ``softplc
iolist`` (the list a commissioning engineer ticks off), the alarm messages, and the web
view and MQTT edge node to come.

Where it is written: each binding of the plant file may carry ``description``, ``unit``
(a UN/CEFACT code or symbol, ``language/units.py``) and, for an int or real signal,
``range: [low, high]`` (its engineering limits); a chart's variables (``description:``
of a memory variable, ``{name: {type: ..., description: ...}}`` of an input or output)
and steps (``description:``) carry a description; an instance its ``description:``.

The API (``IOList(pdef)``):

- ``rows``: the I/O list proper, one ``IORow`` per bound chart input or output, instance
  by instance in plant order, inputs first (signal, direction, type, the point or signal
  it is bound to, NC inversion, its ``Meaning``);
- ``meaning(name)``: the ``Meaning`` (description, unit, range) of any plant name
  (``tester1``, ``tester1.iParo``, ``tester1.sCierres``, ``tester1.gsAbrir``,
  ``tester1.gsAbrir.X``, ``tester1.gsAbrir.T``, ``tester1.SFCError``, ``sim.I0``,
  ``sim.ok``), ``Meaning()`` when nothing is known of it. A bound signal's description
  is its binding's, else its chart's; a TIME value's unit is the millisecond; a driver
  point says which signals it is bound to;
- ``bound_to(point)``: the rows of a driver point (``sim.I0``);
- ``records()``, ``table()`` and ``csv()``: the list as text, for ``softplc iolist``, in
  the order of the terminals (driver points in natural order, inputs before outputs).
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from typing import Any

from runtime.errors import Loc, SourceError
from runtime.language import ast as A
from runtime.language.flagtexts import FLAG_TEXT, HEALTH_TEXT
from runtime.language.grafcetfile import description_text, expect_type
from runtime.language.model import Binding, InstanceDef, PlantDef
from runtime.language.units import MILLISECOND, Unit, find_unit, suggest_unit
from runtime.language.yamlsrc import YList, YMap

#: the I/O list's keys of a binding (beside ``from`` and ``invert``)
IO_KEYS = ("description", "unit", "range")



@dataclass(frozen=True, slots=True)
class Meaning:
    """What a plant name means to a person: its description, its unit of measure, and its
    engineering range (low, high) for a number."""

    description: str = ""
    unit: Unit | None = None
    range: tuple[float, float] | None = None


@dataclass(frozen=True, slots=True)
class IORow:
    """One line of the I/O list: a bound chart input or output of an instance."""

    #: ``instance.signal``
    signal: str
    #: "in" or "out"
    direction: str
    type: A.Type
    #: what it is bound to: ``driver.point`` or ``instance.signal``
    source: str
    #: inverted at the binding (an NC contact)
    invert: bool
    meaning: Meaning


def io_entry(b: Binding, spec: YMap) -> None:
    """Fill ``b``'s I/O list from its binding mapping (``description``, ``unit``,
    ``range``); SourceError at a faulty value. The signal's type is checked later
    (``check_io_entry``)."""
    if "description" in spec:
        b.description = description_text(spec["description"], spec.val_locs["description"])
    if "unit" in spec:
        loc = spec.val_locs["unit"]
        text = spec["unit"]
        if isinstance(text, (int, float)) and not isinstance(text, bool):
            text = str(text)  # a bare 1 (the unit "one") or 59 (ppm)
        text = str(expect_type(text, loc, str, "a unit (a UN/CEFACT code such as CEL, or a "
                                               "symbol such as °C)"))
        unit = find_unit(text.strip())
        if unit is None:
            raise SourceError(loc, f"unknown unit '{text}': expected a UN/CEFACT code (CEL, "
                                   f"BAR, MMT, ...) or a symbol (°C, bar, mm, ...)"
                                   f"{suggest_unit(text.strip())}")
        b.unit = unit
    if "range" in spec:
        b.range = _range(spec["range"], spec.val_locs["range"])


def _range(value: Any, loc: Loc) -> tuple[float, float]:
    items = expect_type(value, loc, YList, "[low, high]: the engineering limits")
    numbers = [v for v in items if isinstance(v, (int, float)) and not isinstance(v, bool)]
    if len(items) != 2 or len(numbers) != 2 or not all(math.isfinite(v) for v in numbers):
        raise SourceError(loc, f"range: expected [low, high], two finite numbers, found "
                               f"{list(items)}")
    low, high = float(numbers[0]), float(numbers[1])
    if not low < high:
        raise SourceError(loc, f"range: expected low < high, found [{numbers[0]}, "
                               f"{numbers[1]}]")
    return low, high


def check_io_entry(b: Binding, spec: YMap, t: A.Type) -> None:
    """A unit or a range belongs to an int or real signal only; SourceError at it."""
    if t in (A.Type.INT, A.Type.REAL):
        return
    for key in ("unit", "range"):
        if key in spec:
            why = ("a time's unit is the millisecond" if t is A.Type.TIME
                   else f"'{b.signal}' is a {t.value}")
            raise SourceError(spec.key_locs[key], f"{key} applies to int and real signals "
                                                  f"only: {why}")


class IOList:
    """The I/O list and the meaning of every name of ``pdef`` (see the module)."""

    def __init__(self, pdef: PlantDef) -> None:
        self.pdef = pdef
        self.rows: list[IORow] = []
        self._by_point: dict[str, list[IORow]] = {}
        self._by_signal: dict[str, IORow] = {}
        for name, idef in pdef.instances.items():
            for direction, section in (("in", idef.inputs), ("out", idef.outputs)):
                for sig, b in section.items():
                    row = IORow(f"{name}.{sig}", direction, _type(idef, sig), b.source,
                                b.invert, self._bound_meaning(idef, sig, b))
                    self.rows.append(row)
                    self._by_signal[row.signal] = row
                    if b.driver is not None:
                        self._by_point.setdefault(b.source, []).append(row)

    @staticmethod
    def _bound_meaning(idef: InstanceDef, sig: str, b: Binding) -> Meaning:
        var = idef.grafcet.variables.get(sig)
        text = b.description or (var.description if var is not None else "")
        if text == "" and sig in FLAG_TEXT:
            text = FLAG_TEXT[sig]
        unit = MILLISECOND if var is not None and var.type is A.Type.TIME else b.unit
        return Meaning(text, unit, b.range)

    def bound_to(self, point: str) -> list[IORow]:
        """The rows bound to driver point ``point`` (several inputs may read one)."""
        return list(self._by_point.get(point, ()))

    def meaning(self, name: str) -> Meaning:
        """What ``name`` means (see the module); ``Meaning()`` if nothing is known."""
        row = self._by_signal.get(name)
        if row is not None:
            return row.meaning
        head, _, rest = name.partition(".")
        idef = self.pdef.instances.get(head)
        if idef is not None:
            return self._instance_meaning(idef, rest)
        if head in self.pdef.drivers:
            if rest == "ok":
                return Meaning(HEALTH_TEXT)
            rows = self._by_point.get(name, [])
            if rows:
                return Meaning("; ".join(_point_text(r) for r in rows),
                               rows[0].meaning.unit, rows[0].meaning.range)
        return Meaning()

    @staticmethod
    def _instance_meaning(idef: InstanceDef, rest: str) -> Meaning:
        g = idef.grafcet
        if not rest:
            return Meaning(idef.description or g.description)
        var = g.variables.get(rest)
        if var is not None:
            text = var.description or FLAG_TEXT.get(rest, "")
            return Meaning(text, MILLISECOND if var.type is A.Type.TIME else None)
        step, _, leaf = rest.rpartition(".")
        if not step:
            step, leaf = rest, ""
        st = g.steps.get(step)
        if st is None or leaf not in ("", "X", "T"):
            return Meaning()
        return Meaning(st.description, MILLISECOND if leaf == "T" else None)

    # -- as text -----------------------------------------------------------------------
    HEADER = ("signal", "point", "NC", "type", "description", "unit", "low", "high")

    def records(self) -> list[tuple[str, ...]]:
        """One tuple per row, the columns of HEADER, in the order of the terminals: the
        driver points, driver by driver in plant order, inputs before outputs, points in
        natural order (I2 before I10); then the signals bound to other instances."""
        drivers = list(self.pdef.drivers)
        out: list[tuple[str, ...]] = []
        for r in sorted(self.rows, key=lambda r: _terminal(r, drivers)):
            m = r.meaning
            low, high = ("", "") if m.range is None else (_num(m.range[0]), _num(m.range[1]))
            out.append((r.signal, r.source, "NC" if r.invert else "",
                        f"{'input' if r.direction == 'in' else 'output'} {r.type.value}",
                        m.description, m.unit.symbol if m.unit else "", low, high))
        return out

    def csv(self) -> str:
        """The list as CSV (comma-separated, a header line, UTF-8 text)."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow([*self.HEADER[:6], "unit code", *self.HEADER[6:]])
        for rec in self.records():
            row = self._by_signal[rec[0]]
            code = row.meaning.unit.code if row.meaning.unit else ""
            w.writerow([*rec[:6], code, *rec[6:]])
        return buf.getvalue()

    def table(self) -> list[str]:
        """The list as aligned columns, for a terminal or a printout."""
        recs: list[tuple[str, ...]] = [(*self.HEADER[:6], "range")]
        recs += [(*r[:6], f"{r[6]} .. {r[7]}" if r[6] else "") for r in self.records()]
        widths = [max(len(r[i]) for r in recs) for i in range(7)]
        return ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
                for r in recs]


def _type(idef: InstanceDef, sig: str) -> A.Type:
    var = idef.grafcet.variables.get(sig)
    return var.type if var is not None else A.Type.BOOL


def _terminal(r: IORow, drivers: list[str]) -> tuple[Any, ...]:
    head, _, point = r.source.partition(".")
    if head not in drivers:
        return (1, 0, r.direction != "in", [], r.signal)
    natural = [(0, int(p), "") if p.isdigit() else (1, 0, p)
               for p in re.split(r"(\d+)", point) if p]
    return (0, drivers.index(head), r.direction != "in", natural, r.signal)


def _point_text(r: IORow) -> str:
    text = f"{'->' if r.direction == 'in' else '<-'} {r.signal}"
    if r.invert:
        text += " (NC, inverted)"
    if r.meaning.description:
        text += f": {r.meaning.description}"
    return text


def _num(x: float) -> str:
    return f"{x:g}"
