"""The plant of a PLCopen file: one instance per chart instance the file runs, and what
each instance's inputs are wired to.

A program POU drawn in FBD or LD that instantiates SFC function blocks is a plant: one
instance per function block instance its body calls, in the order it calls them, named as
the instance; an input wired to another instance's output is bound to it (a link between
instances), an input wired to a variable of the program reads that variable's point (one
point per variable, shared by the instances that read it), a negated input is inverted at
its binding. A program whose task the file's configuration names gives the plant its
cycle. An SFC POU that no program instantiates is one instance of its own, named as the
task's instance of it (else as the POU). What a plant cannot carry (a block of another
type in the program, an input wired to an expression) is one note each.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drivers.durations import parse_literal, strip_time_prefix
from runtime.errors import Loc, SourceError
from runtime.language.lexer import KEYWORDS, is_name
from runtime.language.yamlsrc import YStr
from runtime.plcopen.globalvars import Global
from runtime.plcopen.interface import documentation, softplc_data
from runtime.plcopen.network import Network, NotCarried
from runtime.plcopen.schema import PLCOPEN_NS
from runtime.plcopen.sfcgraph import position
from runtime.plcopen.texts import formatted, plain
from runtime.plcopen.xmltree import Element

#: told of what is left out or changed: (place, message, lost)
Notes = Callable[[Loc, str, bool], None]


@dataclass
class Wire:
    """What a chart input of an instance reads: another instance's output (``link``
    "inst.OUT"), or the point of a variable of the program (``shared`` its name, one point
    for every instance that reads it); ``note`` is shown beside the binding."""

    link: str = ""
    shared: str = ""
    invert: bool = False
    note: str = ""
    description: str = ""
    #: the driver point and located address softplc's export recorded for the variable
    #: (its additional data), "" in a file of another editor
    source: str = ""
    at: str = ""
    #: the address the file gives the program's variable (``%IX0.3``), "" if none
    address: str = ""


@dataclass
class PlantInstance:
    name: str
    pou: str  # the chart's POU
    description: str = ""  # the block's documentation: what this machine is
    inputs: dict[str, Wire] = field(default_factory=dict)  # chart input -> its wire
    outputs: dict[str, str] = field(default_factory=dict)  # chart output -> note beside it
    descriptions: dict[str, str] = field(default_factory=dict)  # output -> description
    #: output -> (driver point, located address) softplc's export recorded
    sources: dict[str, tuple[str, str]] = field(default_factory=dict)
    addresses: dict[str, str] = field(default_factory=dict)  # output -> the file's address


@dataclass
class Plan:
    instances: list[PlantInstance] = field(default_factory=list)
    cycle_ns: int | None = None
    comments: list[str] = field(default_factory=list)  # the programs' comments, one line each
    #: the plant's drivers softplc's export recorded: (name, type, config)
    drivers: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)


def task_of(root: Element) -> dict[str, tuple[str, int | None, Element]]:
    """POU name -> (its instance's name, the interval of the task running it in ns, the
    ``pouInstance``): the first of each POU in the file's configurations."""
    out: dict[str, tuple[str, int | None, Element]] = {}
    instances = root.find("instances", PLCOPEN_NS)
    for holder in instances.iter() if instances is not None else []:
        if holder.tag not in ("task", "resource"):
            continue
        interval = (holder.get("interval") or "").strip() if holder.tag == "task" else ""
        cycle = parse_literal(strip_time_prefix(interval).replace("_", "")) or None
        for e in holder.findall("pouInstance", PLCOPEN_NS):
            name = e.get("name") or ""
            if _is_name(name):
                out.setdefault(e.get("typeName") or "", (name, cycle, e))
    return out


def _is_name(word: str) -> bool:
    return is_name(word) and word.upper() not in KEYWORDS


_SIMPLE = re.compile(r"^(NOT )?(\w+)(?:\.(\w+))?$")


class _Program:
    """One program POU read as a part of the plant."""

    def __init__(self, pou: Element, charts: dict[str, Element], note: Notes,
                 globals_: dict[str, Global], prefix: str) -> None:
        self.pou, self.charts, self.note, self.prefix = pou, charts, note, prefix
        self.name = pou.get("name") or ""
        self.variables: dict[str, tuple[str, Element]] = {}  # lower -> (name, variable)
        for k, g in globals_.items():
            self.variables[k] = ((g.e.get("name") or ""), g.e)
        iface = pou.find("interface", PLCOPEN_NS)
        for lst in iface.children if iface is not None else []:
            for v in lst.findall("variable", PLCOPEN_NS):
                self.variables[(v.get("name") or "").lower()] = (v.get("name") or "", v)
        self.declared: dict[str, tuple[str, str, Element]] = {}  # instance -> (name, POU, var)
        for name, v in self.variables.values():
            t = v.find("type", PLCOPEN_NS)
            d = t.find("derived", PLCOPEN_NS) if t is not None else None
            kind = (d.get("name") or "").lower() if d is not None else ""
            if kind in self.charts:
                self.declared[name.lower()] = (name, self.charts[kind].get("name") or "", v)
        self.instances: list[PlantInstance] = []
        self.wiring: dict[str, list[tuple[str, YStr]]] = {}  # instance -> (input, feed)
        self.typed: set[str] = set()  # variables of derived types noted
        self.comments: list[str] = []

    def read(self) -> list[PlantInstance]:
        body = self.pou.find("body", PLCOPEN_NS)
        net_e = None
        for lang in ("FBD", "LD"):
            net_e = body.find(lang, PLCOPEN_NS) if body is not None else None
            if net_e is not None:
                break
        if net_e is None:
            for name, pou, v in self.declared.values():
                self.note(v.loc, f"program '{self.name}' instantiates {pou} '{name}' in a body "
                                 "softplc does not read (not FBD or LD): the instance's "
                                 "inputs are bound to points of their own", True)
                self.instances.append(PlantInstance(self.prefix + name, pou))
            return self.instances
        for c in sorted((c for c in net_e.children if c.tag == "comment"),
                        key=lambda c: (position(c)[1], position(c)[0])):
            content = c.find("content", PLCOPEN_NS)
            text = " ".join(str(formatted(content)).split()) if content is not None else ""
            if text:
                self.comments.append(f"{self.name}: {text}")
                self.note(c.loc, f"localId {c.get('localId')}: comment of program "
                                 f"'{self.name}' kept as a comment of the plant", False)
        resolve = {(p.get("name") or "").upper(): self.block for p in self.charts.values()}
        net = Network(net_e, resolve=resolve, other=self.other)
        try:
            net.statements()
        except NotCarried as exc:  # pragma: no cover - ``other`` reads every block
            self.note(exc.loc, exc.message, True)
        called = {i.name for i in self.instances}
        for name, pou, v in self.declared.values():
            if self.prefix + name not in called:
                self.note(v.loc, f"{pou} '{name}' of program '{self.name}' left out: the "
                                 "program's body never calls it (it never runs)", True)
        self._wire(net)
        return self.instances

    def block(self, net: Network, e: Element, ref: int, out: str | None,
              trail: tuple[int, ...]) -> YStr:
        """An instance of an imported chart in the program's network."""
        raw = (e.get("instanceName") or "").strip()
        decl = self.declared.get(raw.lower())
        name = decl[0] if decl else raw
        if ref not in net.called:
            net.called.add(ref)
            if decl is None or decl[1].upper() != (e.get("typeName") or "").upper():
                self.note(e.loc, f"localId {ref}: block {e.get('typeName')} '{raw}' left out: "
                                 f"program '{self.name}' declares no such instance", True)
                return plain("?", e.loc)
            if not _is_name(name):
                raise SourceError(e.loc, f"localId {ref}: instance '{name}' of program "
                                         f"'{self.name}': expected a name (letters, digits "
                                         "and '_') for the plant's instance")
            inst = PlantInstance(self.prefix + name, decl[1],
                                 documentation(e, lambda *a, **k: None, ""))
            self.instances.append(inst)
            feeds = []
            for v, text in net.inputs(e, ref, trail):
                if text is not None:
                    feeds.append((v.get("formalParameter") or "", text))
            self.wiring[inst.name] = feeds
        if decl is None:
            return plain("?", e.loc)
        if out is None:
            outs = e.find("outputVariables", PLCOPEN_NS)
            first = outs.find("variable", PLCOPEN_NS) if outs is not None else None
            out = first.get("formalParameter") if first is not None else ""
        return plain(f"{self.prefix}{name}.{out}", e.loc)

    def other(self, net: Network, e: Element, ref: int, out: str | None,
              trail: tuple[int, ...]) -> YStr:
        """A block the plant does not carry: noted once, its outputs read as nothing."""
        if ref not in net.called:
            net.called.add(ref)
            what = e.get("typeName") or "?"
            inst = e.get("instanceName")
            self.note(e.loc, f"localId {ref}: block {what}" + (f" '{inst}'" if inst else "")
                      + f" of program '{self.name}' left out: softplc imports SFC charts "
                        "(a POU in another language has no place in a plant)", True)
        return plain("?", e.loc)

    def _wire(self, net: Network) -> None:
        """Each instance input: a link, a variable's point or a point of its own."""
        fed: dict[str, str] = {}  # program variable (lower) -> "inst.OUT" it is assigned
        for target, value in net.assignments:
            m = _SIMPLE.match(str(value))
            key = str(target).lower()
            if m and not m.group(1) and m.group(3) and any(
                    i.name == m.group(2) for i in self.instances):
                fed.setdefault(key, str(value))
                inst = next(i for i in self.instances if i.name == m.group(2))
                var = self.variables.get(key)
                inst.outputs.setdefault(m.group(3), self._said(str(target), var))
                if var is not None:
                    inst.addresses.setdefault(m.group(3), var[1].get("address") or "")
                    inst.descriptions.setdefault(m.group(3), documentation(
                        var[1], lambda *a, **k: None, ""))
                    point = softplc_data(var[1], "point")
                    if point is not None and point.get("source"):
                        inst.sources.setdefault(m.group(3), (
                            point.get("source") or "", var[1].get("address") or ""))
            elif "?" not in str(value):  # (a block left out is noted once, at the block)
                self.note(target.loc, f"program '{self.name}': '{target} := {value}' left "
                                      "out (a plant binds chart instances; it has no "
                                      "statements)", True)
        for inst in self.instances:
            for param, text in self.wiring.get(inst.name, []):
                m = _SIMPLE.match(str(text))
                invert = bool(m and m.group(1))
                if m and m.group(3) and any(i.name == m.group(2) for i in self.instances):
                    inst.inputs[param] = Wire(link=f"{m.group(2)}.{m.group(3)}",
                                              invert=invert)
                    continue
                var = self.variables.get(m.group(2).lower()) if m and not m.group(3) else None
                if m and var is not None:
                    key = var[0].lower()
                    self._typed(var)
                    if key in fed:
                        inst.inputs[param] = Wire(link=fed[key], invert=invert)
                    else:
                        point = softplc_data(var[1], "point")
                        source = (point.get("source") or "") if point is not None else ""
                        inst.inputs[param] = Wire(
                            shared=self.prefix + var[0], invert=invert,
                            note=self._said(var[0], var),
                            description=documentation(var[1], lambda *a, **k: None, ""),
                            source=source, at=(var[1].get("address") or "") if source else "",
                            address=var[1].get("address") or "")
                    continue
                self.note(text.loc, f"input {param} of instance '{inst.name}' is wired to "
                                    f"'{text}' in program '{self.name}': bound to a point of "
                                    "its own (a binding reads a point or another instance's "
                                    "signal)", True)

    def _typed(self, var: tuple[str, Element]) -> None:
        """A variable of a type of its own (an HMI's, a structure) wired to an instance: a
        point of the plant, what its type adds left out (said once)."""
        t = var[1].find("type", PLCOPEN_NS)
        d = t.find("derived", PLCOPEN_NS) if t is not None else None
        if d is not None and var[0] not in self.typed:
            self.typed.add(var[0])
            self.note(var[1].loc, f"variable '{var[0]}' of program '{self.name}' is a point of "
                                  f"the plant: what its type {d.get('name')} adds is left out",
                      True)

    def _said(self, name: str, var: tuple[str, Element] | None) -> str:
        """The note beside a binding: the program's variable and its address."""
        address = var[1].get("address") if var is not None else None
        return f"{name} of {self.name}" + (f", {address}" if address else "")


def _drivers(pou: Element, note: Notes) -> list[tuple[str, str, dict[str, Any]]]:
    """The plant's drivers softplc's export recorded in the program's additional data
    (``sp:driver``: name, type, the configuration as JSON data)."""
    data = softplc_data(pou, "plant")
    out: list[tuple[str, str, dict[str, Any]]] = []
    for d in data.children if data is not None else []:
        try:
            config = json.loads(d.text or "{}")
        except ValueError:
            config = None
        if not isinstance(config, dict) or not d.get("name") or not d.get("type"):
            note(d.loc, f"driver '{d.get('name')}' of softplc's data left out: its "
                        "configuration is no JSON object", True)
            continue
        out.append((d.get("name") or "", d.get("type") or "", config))
    return out


def plan(root: Element, pous: list[Element], charts: dict[str, Element],
         visible: Callable[[str], dict[str, Global]], note: Notes) -> Plan:
    """The plant's instances: those of the programs that instantiate the imported charts
    (``charts``: the SFC POUs imported, by name in lower case), then one of its own for each
    SFC POU no program instantiates."""
    out = Plan()
    tasks = task_of(root)
    programs = [p for p in pous if p.get("pouType") == "program"
                and (p.get("name") or "").lower() not in charts]
    users = {}
    for p in programs:
        prog = _Program(p, charts, note, visible(p.get("name") or ""), "")
        if prog.declared:
            users[p.get("name") or ""] = prog
    used = [(n, prog) for n, prog in users.items()]
    prefix = len(used) > 1
    cycles: list[tuple[int, Loc]] = []
    for name, prog in used:
        task = tasks.get(name)
        if prefix:
            prog.prefix = f"{task[0] if task else name}_"
        out.instances += prog.read()
        out.comments += prog.comments
        out.drivers += _drivers(prog.pou, note)
        if task is not None and task[1]:
            cycles.append((task[1], task[2].loc))
    taken = {i.pou.lower() for i in out.instances}
    for key, p in charts.items():
        if key in taken:
            continue
        name = p.get("name") or ""
        task = tasks.get(name)
        out.instances.append(PlantInstance(task[0] if task else name, name))
        if task is not None and task[1]:
            cycles.append((task[1], task[2].loc))
    if cycles:
        out.cycle_ns = cycles[0][0]
        for ns, at in cycles[1:]:
            if ns != out.cycle_ns:
                note(at, f"this task's interval ({ns // 1_000_000} ms) left out: a plant "
                         f"has one cycle, the first task's ({out.cycle_ns // 1_000_000} ms)",
                     True)
    return out
