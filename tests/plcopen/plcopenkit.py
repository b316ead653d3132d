"""PLCopen test kit: every chart of configs/ and of the tests, a chart's whole content as
plain data (to compare two charts exactly), export then import in a temporary directory."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path
from typing import Any

from runtime.language.filekind import file_kind
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet
from runtime.plcopen.commands import chart_text
from runtime.plcopen.export import export_chart
from runtime.plcopen.importer import ImportResult, import_file

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parent / "data"


def shape(g: Grafcet) -> dict[str, Any]:
    """Everything a chart says, in file order (two charts with equal shapes are the same
    chart: variables, steps with their actions as written, transitions in priority order
    with their conditions as written, pre, post)."""
    return {
        "name": g.name, "description": g.description, "scan": g.scan,
        "variables": [(v.name, v.kind, v.type, v.init, v.retain, v.renamed_from,
                       v.description, v.iec_type)
                      for v in g.variables.values()],
        "steps": [(s.name, s.initial, s.min_ns, s.max_ns, s.entry, s.exit, s.parent,
                   s.description, s.renamed_from,
                   s.macro and (s.macro.steps, s.macro.entry, s.macro.exit),
                   [a.text.strip() for a in s.actions]) for s in g.steps.values()],
        "transitions": [(t.sources, t.targets, t.text.strip(), t.name, t.index)
                        for t in g.transitions],
        "timers": list(g.timers), "blocks": [(b.name, b.kind) for b in g.blocks.values()],
        "pre": [s.text for s in g.pre], "post": [s.text for s in g.post],
    }


def all_charts() -> list[tuple[str, str]]:
    """(where, text) of every chart file of configs/ and tests/, and of every chart written
    in a test module (a string starting with 'grafcet:'), whether it loads or not."""
    out = []
    for p in sorted([*(ROOT / "configs").rglob("*.yaml"), *(ROOT / "tests").rglob("*.yaml")]):
        if file_kind(str(p)) == "grafcet":
            out.append((str(p.relative_to(ROOT)), p.read_text(encoding="utf-8")))
    for p in sorted((ROOT / "tests").rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                text = textwrap.dedent(node.value)
                if text.lstrip().startswith("grafcet:") and "steps:" in text:
                    out.append((f"{p.relative_to(ROOT)}:{node.lineno}", text))
    return out


def export_file(g: Grafcet, path: Path) -> Path:
    path.write_text(export_chart(g), encoding="utf-8")
    return path


def import_back(xml: Path, out: Path) -> tuple[Grafcet, ImportResult]:
    """The chart of the file's first POU, written as softplc import writes it and loaded."""
    result = import_file(str(xml))
    chart = result.charts[0]
    out.write_text(chart_text(str(xml), chart), encoding="utf-8")
    return load_grafcet(str(out)), result
