"""``softplc export PLANT.yaml``: a plant as one PLCopen project, as Beremiz runs charts.

Each chart of the plant is an SFC function block POU; a program POU drawn in FBD calls one
instance of it per instance of the plant (named as the instance), its inputs wired to the
program's variables (one per driver point, located at the binding's ``at:`` address, with
the binding's description as documentation) or to another instance's output, its outputs
to the program's variables; the project's task runs the program at the plant's cycle.
What PLCopen has no element for (the driver point of each variable, the plant's drivers)
goes into softplc's additional data, so that ``softplc import`` gives the plant back
(docs/plcopen.md, "Exporting a plant").
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from datetime import datetime

from drivers.durations import format_ns
from runtime.errors import SourceError
from runtime.language.model import Binding, Grafcet, PlantDef, VarKind
from runtime.plcopen.export import SP, _data, _text, chart_pou, project_head, task
from runtime.plcopen.schema import EXPORT_TYPES
from runtime.plcopen.xmlwrite import Node, serialize

#: the program's name unless a chart has it
PROGRAM = "Plant"
#: the program's instance in the task
PROGRAM_INSTANCE = "plant0"
#: the geometry of the program's FBD body (px): blocks in a column, variables either side
_BLOCK_X, _IN_X, _OUT_X, _PIN_H, _GAP = 300.0, 40.0, 620.0, 20.0, 60.0


@dataclass
class _Var:
    """A variable of the program: the point it stands for, its type and address."""

    name: str
    source: str
    iec: str
    at: str = ""
    description: str = ""
    ids: list[int] = field(default_factory=list)


def export_plant(p: PlantDef, *, version: str = "", created: datetime | None = None,
                 layout: str = "python") -> str:
    """The PLCopen XML text of plant ``p``."""
    charts: dict[str, Grafcet] = {}
    for inst in p.instances.values():
        g = inst.grafcet
        other = charts.get(g.name.lower())
        if other is not None and other.path != g.path:
            raise SourceError(inst.loc, f"cannot export instance '{inst.name}': its chart is "
                                        f"named '{g.name}' as another chart of the plant "
                                        f"({other.path}): a project has one POU of a name")
        charts.setdefault(g.name.lower(), g)
    program = PROGRAM
    while program.lower() in charts or program.lower() in (i.lower() for i in p.instances):
        program += "_"
    root, pous = project_head(program, version, created)
    for g in charts.values():
        chart_pou(pous, g, "functionBlock", layout)
    _program(pous, p, program)
    task(root, "T#" + format_ns(p.cycle_ns)).add(
        "pouInstance", {"name": PROGRAM_INSTANCE, "typeName": program})
    return serialize(root)


def _var_name(source: str, taken: set[str]) -> str:
    """A program variable's name for driver point ``source`` (``sim.I0`` -> ``sim_I0``)."""
    name = re.sub(r"\W", "_", source)
    if not re.match(r"[A-Za-z_]", name):
        name = "p_" + name
    while name.lower() in taken:
        name += "_"
    taken.add(name.lower())
    return name


def _program(pous: Node, p: PlantDef, name: str) -> None:
    pou = pous.add("pou", {"name": name, "pouType": "program"})
    iface = pou.add("interface")
    ids = iter(range(1, 1_000_000))
    taken = {i.lower() for i in p.instances}
    points: dict[str, _Var] = {}
    block_id = {inst: next(ids) for inst in p.instances}

    def point(b: Binding, g: Grafcet) -> _Var:
        v = points.get(b.source)
        if v is None:
            var = g.variables[b.signal]
            v = _Var(_var_name(b.source, taken), b.source,
                     var.iec_type or EXPORT_TYPES[var.type.value])
            points[b.source] = v
        v.at = v.at or b.at
        v.description = v.description or b.description
        return v

    fbd = pou.add("body").add("FBD")
    elements: list[Node] = []
    y = 40.0
    for inst in p.instances.values():
        g = inst.grafcet
        ins = [v for v in g.variables.values() if v.kind is VarKind.INPUT]
        outs = [v for v in g.variables.values() if v.kind is VarKind.OUTPUT]
        for sig, flag in inst.inputs.items():
            if sig not in g.variables or g.variables[sig].kind is not VarKind.INPUT:
                raise SourceError(flag.loc, f"cannot export the binding of '{inst.name}.{sig}': "
                                         "a chart flag is no input of the chart's function "
                                         "block in PLCopen (remove the binding to export "
                                         "the plant)")
        rows = max(len(ins), len(outs), 1)
        block = Node("block", {"localId": str(block_id[inst.name]), "typeName": g.name,
                               "instanceName": inst.name, "width": "160",
                               "height": f"{(rows + 1) * _PIN_H:g}"})
        _at(block, _BLOCK_X, y)
        inputs = block.add("inputVariables")
        for k, v in enumerate(ins):
            pin_y = y + (k + 1) * _PIN_H
            attrs = {"formalParameter": v.name}
            b: Binding | None = inst.inputs.get(v.name)
            if b is not None and b.invert:
                attrs["negated"] = "true"
            cin = inputs.add("variable", attrs).add("connectionPointIn")
            cin.add("relPosition", {"x": "0", "y": f"{(k + 1) * _PIN_H:g}"})
            if b is None:
                continue
            if b.instance is not None:
                ref = b.ref or ""
                other = p.instances.get(b.instance)
                if other is None or other.grafcet.variables.get(ref) is None or (
                        other.grafcet.variables[ref].kind is not VarKind.OUTPUT):
                    raise SourceError(b.loc, f"cannot export the binding of "
                                             f"'{inst.name}.{v.name}' to '{b.source}': a "
                                             "function block links another's outputs only")
                cin.add("connection", {"refLocalId": str(block_id[b.instance]),
                                       "formalParameter": ref})
                continue
            pv = point(b, g)
            i = next(ids)
            pv.ids.append(i)
            e = Node("inVariable", {"localId": str(i), "height": "20", "width": "120"})
            _at(e, _IN_X, pin_y - 10)
            e.add("connectionPointOut").add("relPosition", {"x": "120", "y": "10"})
            e.add("expression", text=pv.name)
            elements.append(e)
            cin.add("connection", {"refLocalId": str(i)})
        block.add("inOutVariables")
        outputs = block.add("outputVariables")
        for k, v in enumerate(outs):
            pin_y = y + (k + 1) * _PIN_H
            outputs.add("variable", {"formalParameter": v.name}).add(
                "connectionPointOut").add("relPosition", {"x": "160",
                                                          "y": f"{(k + 1) * _PIN_H:g}"})
            ob = inst.outputs.get(v.name)
            if ob is None:
                continue
            pv = point(ob, g)
            i = next(ids)
            e = Node("outVariable", {"localId": str(i), "height": "20", "width": "120"})
            _at(e, _OUT_X, pin_y - 10)
            cin = e.add("connectionPointIn")
            cin.add("relPosition", {"x": "0", "y": "10"})
            cin.add("connection", {"refLocalId": str(block_id[inst.name]),
                                   "formalParameter": v.name})
            e.add("expression", text=pv.name)
            elements.append(e)
        if inst.description:
            _text(block.add("documentation"), inst.description)
        elements.append(block)
        y += (rows + 1) * _PIN_H + _GAP
    fbd.children.extend(elements)
    local = iface.add("localVars")
    for inst in p.instances.values():
        local.add("variable", {"name": inst.name}).add("type").add(
            "derived", {"name": inst.grafcet.name})
    for pv in points.values():
        attrs = {"name": pv.name} | ({"address": pv.at} if pv.at else {})
        var = local.add("variable", attrs)
        var.add("type").add(pv.iec)
        _data(var).add(SP + "point", {"source": pv.source})
        if pv.description:
            _text(var.add("documentation"), pv.description)
    plant = _data(pou).add(SP + "plant")
    for d in p.drivers.values():
        plant.add(SP + "driver", {"name": d.name, "type": d.type},
                  text=json.dumps(d.config, sort_keys=True, default=str))


def _at(e: Node, x: float, y: float) -> None:
    e.add("position", {"x": f"{x:g}", "y": f"{y:g}"})
