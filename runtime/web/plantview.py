"""What the page shows of a plant that does not change while it runs: its instances, each
chart as ``softplc draw`` draws it (SVG, its steps and transitions named for the page to
mark them live), and the I/O list (every input, output and memory variable with its driver
point).

Descriptions: the chart's own (``description:`` of the grafcet file), its steps' (shown as
the step's tooltip), and each signal's from the plant's I/O list (``language/iolist.py``
``IOList.meaning``: the binding's description, else the chart variable's), with its unit."""

from __future__ import annotations

from typing import Any

from runtime.drawing.chart import chart_svg
from runtime.language import ast as A
from runtime.language.coverage import ChartCoverage, of_chart, shading
from runtime.language.iolist import IOList
from runtime.language.model import PlantDef, VarKind


def describe(pdef: PlantDef) -> dict[str, Any]:
    """The plant as the page reads it (``/api/plant``): JSON-ready."""
    instances = []
    iolist = IOList(pdef)
    for name, idef in pdef.instances.items():
        g = idef.grafcet
        io: list[list[str]] = []
        for kind, label in ((VarKind.INPUT, "in"), (VarKind.OUTPUT, "out"),
                            (VarKind.MEMORY, "memory")):
            for var, v in g.variables.items():
                if v.kind is not kind:
                    continue
                b = idef.inputs.get(var) or idef.outputs.get(var)
                source = ""
                if b is not None:
                    source = b.source + (" (inverted)" if b.invert else "")
                meaning = iolist.meaning(f"{name}.{var}")
                text = meaning.description
                if meaning.unit is not None and v.type is not A.Type.TIME:
                    text = f"{text} ({meaning.unit.symbol})" if text else meaning.unit.symbol
                io.append([f"{name}.{var}", label, source, text, v.type.value])
        instances.append({
            "name": name, "grafcet": g.name, "description": g.description,
            "steps": [s.name for s in g.leaf_steps()],
            "transitions": [[t.index, t.text] for t in g.transitions],
            "io": io})
    return {"plant": pdef.path, "instances": instances, "drivers": list(pdef.drivers)}


def chart_of(pdef: PlantDef, instance: str, coverage: list[ChartCoverage] | None = None
             ) -> str | None:
    """The SVG of ``instance``'s chart (None for an unknown instance); ``coverage`` (of
    ``softplc web --coverage``): shaded by it when it holds this chart's."""
    idef = pdef.instances.get(instance)
    if idef is None:
        return None
    g = idef.grafcet
    title = f"{instance}: {g.name}"
    cov = of_chart(coverage, g) if coverage else None
    if cov is not None:
        title += f" (coverage {cov.percent():.1f}%: green reached, red never)"
    svg, _layout = chart_svg(g, title=title, live=True,
                             shading=shading(g, cov) if cov is not None else None)
    return svg
