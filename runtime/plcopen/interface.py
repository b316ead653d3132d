"""A POU's interface as the chart's variables: inputs, outputs, memory, function blocks.

``inputVars`` are inputs, ``outputVars`` outputs, ``localVars`` memory (``retain`` or
``persistent`` lists retained) or function blocks (a ``derived`` type TON, CTU ...); a local
variable located at an input or output address (``%IX0.0``, ``%QX0.1``, Beremiz's way to
reach the I/O) is an input or an output. Types: BOOL bool; SINT ... ULINT, BYTE ... LWORD
int; REAL, LREAL real; TIME time. What has no place in a chart is left out with one note
each (docs/plcopen.md lists them).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

from drivers.durations import parse_literal, strip_time_prefix
from runtime.errors import Loc, SourceError
from runtime.language.shape import DESCRIPTION_MAX
from runtime.language.signatures import FB_MEMBERS
from runtime.plcopen.globalvars import Global
from runtime.plcopen.schema import EXPORT_TYPES, INT_TYPES, PLCOPEN_NS, REAL_TYPES, SOFTPLC_NS
from runtime.plcopen.texts import formatted
from runtime.plcopen.xmltree import Element


class Note(Protocol):
    """Told of something left out or changed (``lost``), or of a choice made that loses
    nothing (``lost=False``)."""

    def __call__(self, loc: Loc, message: str, lost: bool = True) -> None: ...


@dataclass
class Var:
    name: str
    type: str  # bool int real time
    loc: Loc
    init: object = None
    address: str = ""
    renamed_from: str | None = None
    description: str = ""  # its documentation, one line
    iec: str = ""  # the IEC 61131-3 type the file declares (INT, LREAL ...)
    constant: bool = False  # CONSTANT: the chart must not write it
    shared: str = ""  # a VAR_EXTERNAL: the global it is ("resource 'r' X")


def iec_type(v: Var) -> str:
    """The chart's ``iec_type`` for ``v``: the IEC type the file declares, "" when it is the
    one an export declares without it (LINT, LREAL, BOOL, TIME)."""
    return "" if v.iec in ("", EXPORT_TYPES.get(v.type)) else v.iec


@dataclass
class Interface:
    inputs: list[Var] = field(default_factory=list)
    outputs: list[Var] = field(default_factory=list)
    memory: list[tuple[Var, bool]] = field(default_factory=list)  # (variable, retained)
    blocks: list[tuple[str, str, Loc]] = field(default_factory=list)  # (name, kind, place)
    timers: list[tuple[str, Loc]] = field(default_factory=list)

    def names(self) -> list[str]:
        return ([v.name for v in self.inputs] + [v.name for v in self.outputs]
                + [v.name for v, _ in self.memory] + [b[0] for b in self.blocks]
                + [t[0] for t in self.timers])


def softplc_data(e: Element, tag: str) -> Element | None:
    """The element ``tag`` of softplc's additional data in ``e``'s ``addData``, or None."""
    add = e.find("addData", PLCOPEN_NS)
    if add is None:
        return None
    for data in add.findall("data", PLCOPEN_NS):
        if data.get("name") == SOFTPLC_NS:
            for c in data.children:
                if c.ns == SOFTPLC_NS and c.tag == tag:
                    return c
    return None


def _type(var: Element) -> tuple[str, str] | None:
    """("elementary" or "derived", the type's name) of a variable, or None."""
    t = var.find("type", PLCOPEN_NS)
    if t is None or not t.children:
        return None
    inner = t.children[0]
    if inner.tag == "derived":
        return "derived", inner.get("name") or ""
    return "elementary", inner.tag


_INT = re.compile(r"^([+-]?)(?:(2|8|16)#)?([0-9A-Fa-f_]+)$")


def value(text: str, typ: str, loc: Loc) -> object:
    """An initial value (``simpleValue``) of a variable of the language's type ``typ``."""
    raw = text.strip()
    if "#" in raw and raw.split("#", 1)[0].upper() in (
            "BOOL", *INT_TYPES, *REAL_TYPES):  # a typed literal: INT#5
        raw = raw.split("#", 1)[1]
    try:
        if typ == "bool":
            if raw.upper() in ("TRUE", "1"):
                return True
            if raw.upper() in ("FALSE", "0"):
                return False
        elif typ == "int":
            m = _INT.match(raw)
            if m:
                base = int(m.group(2) or 10)
                n = int(m.group(3).replace("_", ""), base)
                return -n if m.group(1) == "-" else n
        elif typ == "real":
            return float(raw.replace("_", ""))
        elif typ == "time":
            ns = parse_literal(strip_time_prefix(raw).replace("_", ""))
            if ns is not None:
                return ns
    except ValueError:
        pass
    raise SourceError(loc, f"expected an initial value of type {typ}, found '{text}'")


def read_interface(pou: Element, note: Note,
                   globals_: Mapping[str, Global] | None = None) -> Interface:
    """The chart's variables from ``pou``'s interface; ``note`` is told what is left out;
    ``globals_``: the global variables the POU's VAR_EXTERNAL may reach, by their name in
    lower case (globalvars.py)."""
    out = Interface()
    iface = pou.find("interface", PLCOPEN_NS)
    if iface is None:
        return out
    for lst in iface.children:
        if lst.ns != PLCOPEN_NS or lst.tag in ("addData", "documentation"):
            continue
        if lst.tag == "returnType":
            note(lst.loc, "the POU's return type is left out (a chart returns nothing)")
            continue
        retained = lst.get("retain") == "true" or lst.get("persistent") == "true"
        constant = lst.get("constant") == "true"
        for v in lst.findall("variable", PLCOPEN_NS):
            if lst.tag == "externalVars":
                _external(out, v, (globals_ or {}).get((v.get("name") or "").lower()), note)
            else:
                _variable(out, lst.tag, v, retained, constant, note)
    timers = softplc_data(iface, "timers")
    if timers is not None:
        for t in timers.findall("timer", SOFTPLC_NS):
            out.timers.append((t.get("name") or "", t.loc))
    return out


def _kind_type(v: Element) -> tuple[str, str]:
    """(the language's type or "", the IEC type's name) of a variable of elementary type."""
    typ = _type(v)
    if typ is None:
        raise SourceError(v.loc, f"variable '{v.get('name') or ''}' has no type")
    t = ("bool" if typ[1] == "BOOL" else "int" if typ[1] in INT_TYPES
         else "real" if typ[1] in REAL_TYPES else "time" if typ[1] == "TIME" else "")
    return (t if typ[0] == "elementary" else ""), typ[1]


def documentation(v: Element, note: Note, what: str) -> str:
    """A variable's ``documentation`` as one line of at most DESCRIPTION_MAX characters (the
    I/O list's description); lines are joined, the rest of a longer text left out (noted)."""
    docu = v.find("documentation", PLCOPEN_NS)
    if docu is None:
        return ""
    text = " ".join("".join(c if c.isprintable() else " " for c in str(formatted(docu)))
                    .split())
    if len(text) > DESCRIPTION_MAX:
        note(docu.loc, f"documentation of {what}: kept its first {DESCRIPTION_MAX} "
                       f"characters of {len(text)} (a description is one line)")
        text = text[:DESCRIPTION_MAX].rstrip()
    return text


def _external(out: Interface, v: Element, glob: Global | None, note: Note) -> None:
    """A VAR_EXTERNAL: the global it names, as the chart's own variable (docs/plcopen.md)."""
    name = v.get("name") or ""
    if glob is None:
        raise SourceError(v.loc, f"VAR_EXTERNAL '{name}': no global variable of that name in "
                                 "the configuration or resource that runs the POU")
    mine, theirs = _kind_type(v), _kind_type(glob.e)
    if mine[1].upper() != theirs[1].upper():
        raise SourceError(v.loc, f"VAR_EXTERNAL '{name}' of type {mine[1]}: the global of "
                                 f"{glob.owner} is of type {theirs[1]} (line {glob.e.loc.line})")
    before = len(out.memory), len(out.inputs), len(out.outputs)
    _variable(out, "localVars", glob.e, glob.retained, glob.constant, note, name=name,
              what=f"global '{name}' of {glob.owner}")
    if (len(out.memory), len(out.inputs), len(out.outputs)) == before:
        return  # left out (its type), noted
    where = "an input" if len(out.inputs) > before[1] else (
        "an output" if len(out.outputs) > before[2] else "memory")
    if where == "memory":
        out.memory[-1][0].shared = f"{glob.owner} '{glob.e.get('name')}'"
    note(v.loc, f"VAR_EXTERNAL{' CONSTANT' if glob.constant else ''} '{name}': the global "
                f"of {glob.owner} (line {glob.e.loc.line}) is {where} of the chart"
                + (" with its initial value" if where == "memory" else ""), lost=False)


def _variable(out: Interface, kind: str, v: Element, retained: bool, constant: bool,
              note: Note, name: str | None = None, what: str = "") -> None:
    name = name if name is not None else (v.get("name") or "")
    what = what or f"'{name}'"
    typ = _type(v)
    if typ is None:
        raise SourceError(v.loc, f"variable '{name}' has no type")
    if kind in ("inOutVars", "externalVars", "globalVars", "accessVars"):
        note(v.loc, f"{kind} variable '{name}' left out: a chart has inputs, outputs and "
                    "memory only (declare it in the POU's inputVars, outputVars or localVars)")
        return
    address = v.get("address") or ""
    if address:
        located = address.upper()[1:2]  # %I, %Q, %M
        kind = {"I": "inputVars", "Q": "outputVars"}.get(located, kind)
    if typ[0] == "derived":
        if typ[1] in FB_MEMBERS and kind in ("localVars", "tempVars"):
            out.blocks.append((name, typ[1], v.loc))
            return
        note(v.loc, f"variable {what} of type {typ[1]} left out: softplc's types are BOOL, "
                    f"integers, REAL/LREAL and TIME, and the blocks {' '.join(FB_MEMBERS)}")
        return
    t, iec = _kind_type(v)
    if not t:
        note(v.loc, f"variable {what} of type {typ[1]} left out: softplc's types are BOOL, "
                    "integers, REAL/LREAL and TIME")
        return
    init_e = v.find("initialValue", PLCOPEN_NS)
    simple = init_e.find("simpleValue", PLCOPEN_NS) if init_e is not None else None
    if init_e is not None and simple is None:
        raise SourceError(init_e.loc, f"expected a simple initial value for '{name}'")
    init = value(simple.get("value") or "", t, simple.loc) if simple is not None else None
    var = Var(name, t, v.loc, init, address, description=documentation(v, note, what),
              iec=iec.upper(), constant=constant)
    sp = softplc_data(v, "variable")
    if sp is not None:
        var.renamed_from = sp.get("renamed_from")
    if kind in ("inputVars", "outputVars"):
        if init:
            note(simple.loc if simple is not None else v.loc,
                 f"initial value of {what} left out: an {kind[:-5]}'s value comes from its "
                 "binding in the plant")
        if constant:
            note(v.loc, f"CONSTANT of {what} left out: an {kind[:-5]} is bound in the plant")
        (out.inputs if kind == "inputVars" else out.outputs).append(var)
        return
    if kind == "tempVars":
        note(v.loc, f"VAR_TEMP {what} kept as memory: it keeps its value from scan to scan")
    if address:
        note(v.loc, f"address {address} of {what} left out: memory is the chart's own")
    if constant and not what.startswith("global "):
        note(v.loc, f"CONSTANT {what} is memory of the chart with its initial value",
             lost=False)
    out.memory.append((var, retained))
