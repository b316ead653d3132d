"""Round trip: every chart of configs/ and of the tests, exported, is valid against
tc6_xml_v201.xsd and imports back as the same chart (every key, every text as written, every
order), and ``softplc diff`` says "no change"; the Structured Text the export writes means,
read back without softplc's data, what the chart's own texts mean."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.errors import SourceError
from runtime.language import ast as A
from runtime.language.grafcetfile import load_grafcet
from runtime.language.model import Grafcet, Transition
from runtime.language.unparse import unparse
from tests.plcopen.plcopenkit import all_charts, export_file, import_back, shape


def crossing(g: Grafcet) -> list[Transition]:
    """The transitions written at one level (the chart, or a macro-step's expansion) that
    link a step of another level."""
    level = {id(t): s.name for s in g.steps.values() if s.macro is not None
             for t in s.macro.transitions}
    return [t for t in g.transitions
            if any(g.steps[n].parent != level.get(id(t)) for n in (*t.sources, *t.targets))]


def _loadable(tmp: Path) -> tuple[list[tuple[str, str]], list[str]]:
    """(where, text) of every chart that loads, and where those with a crossing transition
    are."""
    out, crossings = [], []
    for i, (where, text) in enumerate(all_charts()):
        p = tmp / f"c{i}.yaml"
        p.write_text(text, encoding="utf-8")
        try:
            g = load_grafcet(str(p))
        except Exception:  # noqa: BLE001 - a test's chart that is meant to be refused
            continue
        out.append((where, text))
        if crossing(g):
            crossings.append(where)
    return out, crossings


with tempfile.TemporaryDirectory(prefix="plcopen-charts-") as _tmp:
    CHARTS, CROSSING = _loadable(Path(_tmp))
#: the charts whose texts an export carries (all but those refused for a crossing link)
EXPORTED = [(w, t) for w, t in CHARTS if w not in CROSSING]


def test_the_charts_are_found() -> None:
    """configs/ and the tests hold over a hundred charts that load: all of them are tried
    below (a search that found none would pass every test)."""
    assert len(CHARTS) > 100
    assert any(w.startswith("configs/reactor") for w, _ in CHARTS)  # a macro-step
    assert any(w.startswith("configs/seed004") for w, _ in CHARTS)  # scan: codesys
    # a transition linking steps of two levels is refused (below): only the test of that
    # refusal writes one
    assert [w.partition(":")[0] for w in CROSSING] == ["tests/plcopen/test_plcopen_cli.py"]


@pytest.mark.parametrize(("where", "text"), CHARTS, ids=[w for w, _ in CHARTS])
def test_export_is_valid_and_imports_back_as_the_same_chart(
        where: str, text: str, tmp_path: Path, tc6: Any,
        capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "chart.yaml"
    src.write_text(text, encoding="utf-8")
    g = load_grafcet(str(src))
    if crossing(g):
        # PLCopen keeps each expansion in its macro-step's body: a transition written at
        # one level between steps of two levels has no place, and is refused at its line
        with pytest.raises(SourceError) as e:
            export_file(g, tmp_path / "chart.xml")
        assert e.value.message.startswith("cannot export transition")
        assert e.value.loc == crossing(g)[0].loc
        return
    xml = export_file(g, tmp_path / "chart.xml")
    tc6.validate(str(xml))
    back, _ = import_back(xml, tmp_path / "back.yaml")
    assert shape(back) == shape(g)
    capsys.readouterr()
    assert main(["diff", str(src), str(tmp_path / "back.yaml")]) == 0
    assert capsys.readouterr().out == "no change\ncan be applied online\n"


# -- the Structured Text of an export means what the chart's texts mean ----------------------
def tree(n: A.Node | None) -> Any:
    """A typed syntax tree as plain data (independent of any printer)."""
    if n is None:
        return None
    if isinstance(n, A.Lit):  # 0 where a bool is wanted and FALSE are the same constant
        return ("Lit", n.type, bool(n.value) if n.type is A.Type.BOOL else n.value)
    fields: list[Any] = [type(n).__name__, n.type]
    for k in n.__slots__ if hasattr(n, "__slots__") else ():
        if k in ("start", "end", "text", "type"):
            continue
        v = getattr(n, k, None)
        if isinstance(v, A.Node):
            v = tree(v)
        elif isinstance(v, list):
            v = [tree(x) if isinstance(x, A.Node) else _items(x) for x in v]
        fields.append((k, v))
    return tuple(fields)


def _items(x: Any) -> Any:
    if isinstance(x, tuple):
        return tuple(tree(i) if isinstance(i, A.Node) else _items(i) for i in x)
    if isinstance(x, list):
        return [tree(i) if isinstance(i, A.Node) else _items(i) for i in x]
    return x


def meaning(g: Grafcet) -> dict[str, Any]:
    return {
        "transitions": [(t.sources, t.targets, unparse(t.cond), tree(t.cond))
                        for t in g.transitions],
        "actions": [(a.step, a.qualifier, a.time_ns, a.target, tree(a.cond), tree(a.event),
                     [tree(s) for s in a.body or []]) for a in g.actions()],
    }


STRIP = re.compile(r"<sp:text>.*?</sp:text>|<sp:text/>", re.DOTALL)


@pytest.mark.parametrize(("where", "text"), EXPORTED, ids=[w for w, _ in EXPORTED])
def test_the_exported_structured_text_means_the_same(where: str, text: str,
                                                      tmp_path: Path) -> None:
    """Without the texts as written (an editor changed them, or a tool dropped softplc's
    data), conditions and actions are read from the ST the export wrote: the same typed
    trees as the chart's own texts (edges as RE/FE, times as T#, the seed's + and · as OR
    and AND where they were logical)."""
    src = tmp_path / "chart.yaml"
    src.write_text(text, encoding="utf-8")
    g = load_grafcet(str(src))
    xml = export_file(g, tmp_path / "chart.xml")
    stripped = STRIP.sub("", xml.read_text(encoding="utf-8"))
    assert "<sp:text>" not in stripped
    xml.write_text(stripped, encoding="utf-8")
    back, _ = import_back(xml, tmp_path / "back.yaml")
    assert meaning(back) == meaning(g)
