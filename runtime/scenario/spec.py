"""A scenario file read and checked against its plant's definition: the simulation
script's ``set:`` (or a ``script:`` it names) and the expectations of ``expect:``, every name
resolved to a column of the trace and every time to a scan (docs/testing-charts.md, "The
scenario file"). No plant is built (``softplc check`` reads scenarios too); ``run.py``
builds it.

Every fault is a SourceError at its place in the file, before anything runs.
"""

from __future__ import annotations

import operator
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.durations import format_ns
from runtime.engine.names import PlantNames
from runtime.engine.script import Change, read_script, script_of
from runtime.errors import Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.filekind import SCENARIO, SHAPES
from runtime.language.model import PlantDef, VarKind
from runtime.language.plantfile import load_plant
from runtime.language.shape import (
    expect_type,
    time_value,
)
from runtime.language.signatures import FB_MEMBERS
from runtime.language.yamlsrc import YList, YMap, load_yaml

T = A.Type

#: a comparison written before a value: ``">= 4"``, ``"!= gsAbrir"``
_OP = re.compile(r"\s*(==|!=|<=|>=|<|>)\s*(.*?)\s*\Z", re.S)
OPS: dict[str, Callable[[Any, Any], bool]] = {
    "==": operator.eq, "!=": operator.ne, "<": operator.lt, "<=": operator.le,
    ">": operator.gt, ">=": operator.ge}


@dataclass(frozen=True, slots=True)
class Check:
    """``name OP value`` on one column of the trace (values as the trace holds them: bools
    0/1, times in whole ms)."""

    name: str
    column: str
    type: A.Type
    op: str
    value: Any
    loc: Loc  # of the name in the file

    def test(self, v: Any) -> bool:
        return OPS[self.op](v, self.value)

    def show(self, v: Any) -> str:
        """A value of this column as a person reads it."""
        if self.type is T.TIME and isinstance(v, int):
            return format_ns(v * 1_000_000)
        return str(v)

    def text(self) -> str:
        """``tester1.oAbrir = 1``, ``tester1.gsAbrir.T >= 300ms``."""
        return f"{self.name} {'=' if self.op == '==' else self.op} {self.show(self.value)}"


@dataclass(frozen=True, slots=True)
class Expectation:
    """One entry of ``expect:``: its kind (a key of SHAPES), where it is, its checks (all
    of them in one scan), its window of scans (``first`` to ``last``, inclusive), and for
    ``on_rise``/``on_fall`` the name whose edge it waits for; for ``rises``, its checks
    are counts of rising edges."""

    kind: str
    loc: Loc
    checks: tuple[Check, ...]
    first: int
    last: int
    trigger: Check | None
    title: str  # what it says, for the report ("at 1s500ms", "never from 0s to 500ms")
    span: str = ""  # its window, "from 0s to 500ms"
    name: str = ""  # the name the file gives it (``name:``)

    @property
    def named(self) -> str:
        """``NAME: `` to begin its failure's line with, or ""."""
        return f"{self.name}: " if self.name else ""


@dataclass
class ScenarioSpec:
    """A scenario read: its plant's file and definition, the input changes (sorted by time,
    file order kept at equal times), its number of scans, its expectations."""

    path: str
    plant_path: str
    pdef: PlantDef
    changes: list[Change]
    cycles: int
    expectations: list[Expectation]

    @property
    def columns(self) -> list[str]:
        """The trace's columns the expectations read."""
        cols = {c.column for e in self.expectations for c in e.checks}
        cols |= {e.trigger.column for e in self.expectations if e.trigger is not None}
        return sorted(cols)


def read_scenario(path: str) -> ScenarioSpec:
    """The scenario at ``path``, checked against its plant's definition; SourceError at the
    first fault."""
    doc = load_yaml(path)
    if not isinstance(doc, YMap) or "expect" not in doc:
        raise SourceError(Loc(path, 1, 1), "expected a scenario: a mapping with 'plant:', "
                                           "'set:' or 'script:', and 'expect:'")
    SCENARIO.check(doc)
    if "plant" not in doc:
        raise SourceError(doc.loc, "a scenario needs 'plant: FILE' (the plant it runs, "
                                   "relative to the scenario)")
    plant_path = _beside(path, doc, "plant")
    pdef = load_plant(plant_path)
    names = PlantNames(pdef)
    own = script_of(doc, names, need_length=False, shape=SCENARIO)
    changes: list[Change] = []
    duration, cycles = own.duration_ns, own.cycles
    if "script" in doc:
        script = read_script(_beside(path, doc, "script"), names, need_length=False)
        changes += script.changes
        if duration is None and cycles is None:
            duration, cycles = script.duration_ns, script.cycles
    changes += own.changes
    changes.sort(key=lambda c: c.at_ns)  # stable: the script's first at equal times
    if duration is None and cycles is None:
        raise SourceError(doc.loc, "the scenario needs 'duration:' or 'cycles:' (or a "
                                   "'script:' that has one)")
    if cycles is None:
        assert duration is not None
        cycles = -(-duration // pdef.cycle_ns)
    reader = _Reader(pdef, names, cycles)
    items = expect_type(doc["expect"], doc.val_locs["expect"], YList,
                        "a list of expectations ({at: TIME, expect: {name: value}}, ...)")
    exps = [reader.expectation(item, loc)
            for item, loc in zip(items, getattr(items, "locs", []), strict=True)]
    if not exps:
        raise SourceError(doc.val_locs["expect"], "expected at least one expectation")
    return ScenarioSpec(path, plant_path, pdef, changes, cycles, exps)


def _beside(path: str, doc: YMap, key: str) -> str:
    """The file that ``key:`` names, relative to the scenario's directory."""
    value = expect_type(doc[key], doc.val_locs[key], str, "a file name")
    return os.path.join(os.path.dirname(path), value)


def traced(pdef: PlantDef, names: PlantNames) -> dict[str, tuple[str, A.Type | None]]:
    """Every name an expectation may read, with its trace column and its type (None for a
    driver's point: a raw number), as the trace has them (docs/semantics.md, the trace):
    an instance's variables and flags, each step's X and T (column ``.T_ms``), each
    function block's outputs; each driver's declared points and ``ok``."""
    out: dict[str, tuple[str, A.Type | None]] = {}
    for iname, idef in pdef.instances.items():
        g = idef.grafcet
        for v in g.variables.values():
            if v.kind is not VarKind.SYSTEM:
                out[f"{iname}.{v.name}"] = (f"{iname}.{v.name}", v.type)
        for s in g.steps:
            out[f"{iname}.{s}.X"] = (f"{iname}.{s}.X", T.BOOL)
            out[f"{iname}.{s}.T"] = (f"{iname}.{s}.T_ms", T.TIME)
        for b in g.blocks.values():
            for member, (mtype, is_input) in FB_MEMBERS[b.kind].items():
                if not is_input:
                    key = f"{iname}.{b.name}.{member}"
                    out[key] = (key, mtype)
    for dname, (ins, outs) in names.points.items():
        for p in [*ins, *outs]:
            out[f"{dname}.{p}"] = (f"{dname}.{p}", None)
        out[f"{dname}.ok"] = (f"{dname}.ok", T.BOOL)
    return out


class _Reader:
    """Reads expectations against one plant's definition: the names the trace has and
    their types, its cycle and the number of scans of the run."""

    def __init__(self, pdef: PlantDef, names: PlantNames, scans: int) -> None:
        self.cycle_ns = pdef.cycle_ns
        self.scans = scans
        self.names = traced(pdef, names)

    # -- times and scans ---------------------------------------------------------------
    def end(self) -> str:
        last = self.scans - 1
        return f"the last scan of the run is cycle {last} (t = {format_ns(last * self.cycle_ns)})"

    def scan_at(self, m: YMap, key: str) -> int:
        """The first scan at or after the time of ``key:`` (as a script's change is seen)."""
        ns = time_value(m[key], m.val_locs[key], key)
        k = -(-ns // self.cycle_ns)
        if k >= self.scans:
            raise SourceError(m.val_locs[key], f"{key}: {format_ns(ns)} is after the run: "
                                               f"{self.end()}")
        return k

    def window(self, m: YMap) -> tuple[int, int]:
        """The scans with ``from`` <= t < ``to`` (default: the whole run)."""
        first, last = 0, self.scans - 1
        if "from" in m:
            first = self.scan_at(m, "from")
        if "to" in m:
            to = time_value(m["to"], m.val_locs["to"], "to")
            if to > self.scans * self.cycle_ns:
                raise SourceError(m.val_locs["to"], f"to: {format_ns(to)} is after the run "
                                  f"(it lasts {format_ns(self.scans * self.cycle_ns)})")
            last = -(-to // self.cycle_ns) - 1
        if last < first:
            raise SourceError(m.loc, "empty window: no scan has from <= t < to")
        return first, last

    def span(self, first: int, last: int) -> str:
        return (f"from {format_ns(first * self.cycle_ns)} to "
                f"{format_ns((last + 1) * self.cycle_ns)}")

    # -- expectations ------------------------------------------------------------------
    def expectation(self, item: Any, loc: Loc) -> Expectation:
        m = expect_type(item, loc, YMap, "an expectation ({at: TIME, expect: {name: value}})")
        kinds = [k for k in SHAPES if k in m]
        if "cycle" in m and "at" not in kinds:
            kinds.insert(0, "at")
        if len(kinds) != 1:
            what = ("'at:'/'cycle:' with 'expect:', 'on_rise:'/'on_fall:' with 'expect:', "
                    "'never:', 'always:', 'rises:'")
            raise SourceError(m.loc, f"an expectation needs one of {what}" if not kinds else
                              f"an expectation has one of {what}: this one has "
                              f"{', '.join(kinds)}")
        kind = kinds[0]
        SHAPES[kind].check(m)
        name = ""
        if "name" in m:
            name = expect_type(m["name"], m.val_locs["name"], str, "a name for the report")
        if kind == "at":
            return self._at(m, name)
        first, last = self.window(m)
        span = self.span(first, last)
        if kind in ("on_rise", "on_fall"):
            if "expect" not in m:
                edge = "rise" if kind == "on_rise" else "fall"
                raise SourceError(m.loc, f"an expectation on a {edge} needs 'expect: {{name: "
                                         f"value}}' (what the scan where it {edge}s holds)")
            trigger = self.check(m, kind, m[kind], m.val_locs[kind], None, bool_only=True)
            edge = "rises" if kind == "on_rise" else "falls"
            return Expectation(kind, m.loc, self.checks(m, "expect"), first, last, trigger,
                               name or f"where {trigger.name} {edge} {span}", span, name)
        if kind == "rises":
            return Expectation(kind, m.loc, self.checks(m, "rises", counts=True), first,
                               last, None, name or f"rising edges {span}", span, name)
        return Expectation(kind, m.loc, self.checks(m, kind), first, last, None,
                           name or f"{kind} {span}", span, name)

    def _at(self, m: YMap, name: str) -> Expectation:
        if "expect" not in m:
            raise SourceError(m.loc, "an expectation at a time needs 'expect: {name: value}'")
        if "at" in m and "cycle" in m:
            raise SourceError(m.key_locs["cycle"], "give 'at:' or 'cycle:', not both")
        if "cycle" in m:
            k = expect_type(m["cycle"], m.val_locs["cycle"], int, "a cycle number")
            if not 0 <= k < self.scans:
                raise SourceError(m.val_locs["cycle"], f"cycle {k} is not in the run: "
                                                       f"{self.end()}")
            when = f"cycle {k}"
        else:
            k = self.scan_at(m, "at")
            when = f"at {format_ns(time_value(m['at'], m.val_locs['at'], 'at'))}"
        last = k
        if "within" in m:
            if "cycle" in m:
                raise SourceError(m.key_locs["within"], "'within:' goes with 'at:', not "
                                                        "'cycle:'")
            w = time_value(m["within"], m.val_locs["within"], "within")
            last = min((k * self.cycle_ns + w) // self.cycle_ns, self.scans - 1)
            when += f" within {format_ns(w)}"
        return Expectation("within" if last > k else "at", m.loc, self.checks(m, "expect"),
                           k, last, None, name or when, self.span(k, last), name)

    def checks(self, m: YMap, key: str, counts: bool = False) -> tuple[Check, ...]:
        spec = expect_type(m[key], m.val_locs[key], YMap, "a mapping {name: value, ...}")
        if not spec:
            raise SourceError(m.val_locs[key], "expected at least one name: value")
        return tuple(self.check(spec, name, name, spec.key_locs[name], spec[name],
                                counts=counts, vloc=spec.val_locs[name])
                     for name in spec)

    def check(self, m: YMap, key: str, name: Any, loc: Loc, value: Any, *,
              bool_only: bool = False, counts: bool = False, vloc: Loc | None = None
              ) -> Check:
        """The check of ``name`` against ``value`` (None: only resolve the name)."""
        name = expect_type(name, loc, str, "a name (instance.signal, instance.STEP.X, "
                                           "driver.point)")
        column, typed = self.resolve(name, loc)
        if (bool_only or counts) and typed not in (T.BOOL, None):
            raise SourceError(loc, f"'{name}' is {_a(typed)}: edges are of bools")
        typ = T.INT if typed is None else typed  # a point: a raw number
        if value is None:
            return Check(name, column, typ, "==", 1, loc)
        vloc = vloc or loc
        if counts:
            op, n = _operator(value, vloc, ("==", "!=", "<", "<=", ">", ">="))
            count = n if isinstance(n, int) and not isinstance(n, bool) else _int(n, vloc)
            if count < 0:
                raise SourceError(vloc, "expected a number of rising edges, 0 or more")
            return Check(name, column, T.INT, op, count, loc)
        op, operand = _operator(value, vloc, tuple(OPS) if typ in (T.INT, T.REAL, T.TIME)
                                else ("==", "!="))
        if typed is None and isinstance(operand, bool):  # a point's bit: 0 or 1
            operand = int(operand)
        return Check(name, column, typ, op, _typed(typ, operand, vloc, name), loc)

    def resolve(self, name: str, loc: Loc) -> tuple[str, A.Type | None]:
        """The trace column of ``name`` and its type (None: a driver's point)."""
        found = self.names.get(name)
        if found is None:
            raise SourceError(loc, f"unknown name '{name}': expected instance.variable, "
                                   f"instance.STEP.X, instance.STEP.T or driver.point"
                                   f"{suggest(name, self.names)}")
        return found


def _operator(value: Any, loc: Loc, allowed: tuple[str, ...]) -> tuple[str, Any]:
    """``(op, operand)`` of a value: ``">= 4"`` -> (">=", "4"), ``1`` -> ("==", 1)."""
    if isinstance(value, str):
        m = _OP.match(value)
        if m is not None:
            if m.group(1) not in allowed:
                raise SourceError(loc, f"'{m.group(1)}' compares numbers and times: expected "
                                       f"{' or '.join(allowed)}")
            return m.group(1), m.group(2)
    if isinstance(value, YMap | YList) or value is None:
        raise SourceError(loc, "expected a value (1, 0, 250ms, '>= 4'), found "
                               f"{'nothing' if value is None else 'a mapping or a list'}")
    return "==", value


def _int(v: Any, loc: Loc) -> int:
    try:
        return int(str(v).strip(), 10)
    except ValueError:
        raise SourceError(loc, f"expected a whole number, found '{v}'") from None


def _typed(typ: A.Type, v: Any, loc: Loc, name: str) -> Any:
    """The expected value as the trace holds values of ``typ``: bools 0/1, times in ms."""
    text = v.strip() if isinstance(v, str) else v
    if typ is T.BOOL:
        words = {"1": 1, "0": 0, "true": 1, "false": 0}
        if isinstance(text, str) and text.lower() in words:
            return words[text.lower()]
        if text in (0, 1):  # True and False too
            return int(text)
        raise SourceError(loc, f"'{name}' is a bool: expected 0 or 1 (true/false), found "
                               f"{text!r}")
    if typ is T.TIME:
        ns = time_value(text, loc, name)
        if ns % 1_000_000:
            raise SourceError(loc, f"the trace holds times in whole ms: {format_ns(ns)} for "
                                   f"'{name}' is not one")
        return ns // 1_000_000
    if typ is T.STRING:
        return str(text)
    try:
        if isinstance(text, bool):
            raise ValueError
        if typ is T.REAL:
            return float(text)
        return text if isinstance(text, int) else int(str(text), 10)
    except ValueError:
        raise SourceError(loc, f"'{name}' is {_a(typ)}: expected a number, found "
                               f"{text!r}") from None


def _a(typ: A.Type) -> str:
    """``an int``, ``a time``."""
    word = typ.value.lower()
    return f"{'an' if word[0] in 'aeiou' else 'a'} {word}"
