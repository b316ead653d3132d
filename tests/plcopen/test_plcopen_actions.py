"""A POU action (``pou/actions/action``) keeps its identity through import and export: the
importer marks each step action that came from it (``N (* action Blink *) ...``), the
export writes ``<actions><action name="Blink">`` once and action blocks that reference it,
and an import of that export gives the same chart (docs/plcopen.md, "POU actions")."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.errors import SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.plcopen.export import export_chart
from tests.plcopen.plcopenkit import DATA, import_back, shape

ST_ACTION = ('<action name="{name}"><body><ST><xhtml:p><![CDATA[{body}]]></xhtml:p></ST>'
             '</body></action>')


def _file(actions: str, blocks: dict[str, str]) -> str:
    """A two-step loop S0 <-> S1 whose steps carry the action blocks ``blocks``."""
    steps = ""
    for k, s in enumerate(("S0", "S1")):
        cin = f'<connectionPointIn><connection refLocalId="{11 if k else 12}"/></connectionPointIn>'
        steps += (f'<step localId="{k + 1}" name="{s}" initialStep="{"false" if k else "true"}">'
                  f'<position x="0" y="{k * 100}"/>{cin}<connectionPointOut/></step>')
        if s in blocks:
            steps += (f'<actionBlock localId="{k + 20}"><position x="80" y="{k * 100}"/>'
                      f'<connectionPointIn><connection refLocalId="{k + 1}"/>'
                      f'</connectionPointIn>{blocks[s]}</actionBlock>')
    trans = "".join(
        f'<transition localId="{11 + k}"><position x="0" y="{50 + 100 * k}"/>'
        f'<connectionPointIn><connection refLocalId="{k + 1}"/></connectionPointIn>'
        f'<condition><inline name=""><ST><xhtml:p>{c}</xhtml:p></ST></inline></condition>'
        '</transition>' for k, c in enumerate(("Go", "NOT Go")))
    return ('<?xml version="1.0" encoding="utf-8"?>\n<project xmlns="http://www.plcopen.org/'
            'xml/tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml"><types><dataTypes/>'
            '<pous><pou name="Blinker" pouType="program"><interface><inputVars>'
            '<variable name="Go"><type><BOOL/></type></variable></inputVars><outputVars>'
            '<variable name="Lamp"><type><BOOL/></type></variable></outputVars><localVars>'
            '<variable name="n"><type><INT/></type></variable></localVars></interface>'
            f'<actions>{actions}</actions><body><SFC>{steps}{trans}</SFC></body></pou>'
            '</pous></types></project>\n')


def _ref(q: str, name: str, extra: str = "") -> str:
    return f'<action localId="0" qualifier="{q}"{extra}><reference name="{name}"/></action>'


SHARED = _file(ST_ACTION.format(name="Blink", body="Lamp := NOT Lamp;\nn := n + 1;"),
               {"S0": _ref("N", "Blink"), "S1": _ref("N", "Blink") + _ref("P1", "Blink")})


def _pou_actions(xml: str) -> list[str]:
    """The names of the POU actions of an exported project."""
    return re.findall(r'<action name="(\w+)">', xml)


def _references(xml: str) -> list[str]:
    return re.findall(r'<reference name="(\w+)"/>', xml)


def test_a_pou_action_is_exported_once_and_referenced(tmp_path: Path, tc6: Any) -> None:
    """Before: each step action was exported as an inline ST body (three copies of Blink's
    statements, no ``<actions>``)."""
    (tmp_path / "f.xml").write_text(SHARED, encoding="utf-8")
    g, _ = import_back(tmp_path / "f.xml", tmp_path / "Blinker.yaml")
    assert [a.text.strip() for a in g.steps["S1"].actions] == [
        "N (* action Blink *) Lamp := NOT Lamp;\nn := n + 1;",
        "P1 (* action Blink *) Lamp := NOT Lamp;\nn := n + 1;"]
    xml = export_chart(g)
    assert _pou_actions(xml) == ["Blink"]
    assert _references(xml) == ["Blink", "Blink", "Blink"]
    assert "<inline>" not in xml.split("<body>", 1)[1].split("</SFC>")[0].replace(
        "<inline name=", "")  # no action inline (the conditions are)
    (tmp_path / "e.xml").write_text(xml, encoding="utf-8")
    tc6.validate(str(tmp_path / "e.xml"))


def test_import_export_import_gives_the_same_chart(tmp_path: Path) -> None:
    (tmp_path / "f.xml").write_text(SHARED, encoding="utf-8")
    first = tmp_path / "a" / "Blinker.yaml"
    first.parent.mkdir()
    g, _ = import_back(tmp_path / "f.xml", first)
    (tmp_path / "e.xml").write_text(export_chart(g), encoding="utf-8")
    second = tmp_path / "b" / "Blinker.yaml"
    second.parent.mkdir()
    again, _ = import_back(tmp_path / "e.xml", second)
    assert shape(again) == shape(g)
    assert main(["diff", str(first), str(second)]) == 0


def test_without_softplc_data_the_action_comes_back_from_its_body(tmp_path: Path) -> None:
    """An editor that drops softplc's additional data: the action is read from the POU
    action's body again, and its mark is written again."""
    (tmp_path / "f.xml").write_text(SHARED, encoding="utf-8")
    g, _ = import_back(tmp_path / "f.xml", tmp_path / "a.yaml")
    xml = re.sub(r"<addData>.*?</addData>", "", export_chart(g), flags=re.S)
    (tmp_path / "e.xml").write_text(xml, encoding="utf-8")
    again, _ = import_back(tmp_path / "e.xml", tmp_path / "b.yaml")
    assert [a.text.strip() for a in again.steps["S1"].actions] == [
        "N (* action Blink *) Lamp := NOT Lamp;\nn := n + 1;",
        "P1 (* action Blink *) Lamp := NOT Lamp;\nn := n + 1;"]


def test_a_body_edited_in_the_editor_is_read_from_the_file(tmp_path: Path) -> None:
    """The POU action's body changed in the editor after the export: the import takes the
    new body (softplc's text as written describes the old one), in every step naming it."""
    (tmp_path / "f.xml").write_text(SHARED, encoding="utf-8")
    g, _ = import_back(tmp_path / "f.xml", tmp_path / "a.yaml")
    xml = export_chart(g).replace("n := n + 1;", "n := n + 2;")
    (tmp_path / "e.xml").write_text(xml, encoding="utf-8")
    again, _ = import_back(tmp_path / "e.xml", tmp_path / "b.yaml")
    texts = [a.text for s in again.steps.values() for a in s.actions]
    assert len(texts) == 3 and all("n := n + 2;" in t and "(* action Blink *)" in t
                                   for t in texts)


def test_an_ld_action_is_exported_as_st_once(tmp_path: Path, tc6: Any) -> None:
    """beremiz_cell.xml's LD action Counting: exported as one ST POU action (the
    statements the import read from its network), referenced by its step."""
    g, _ = import_back(DATA / "beremiz_cell.xml", tmp_path / "cell.yaml")
    marked = [a.text for s in g.steps.values() for a in s.actions
              if "(* action Counting *)" in a.text]
    assert marked
    xml = export_chart(g)
    assert _pou_actions(xml) == ["Counting"]
    assert _references(xml).count("Counting") == len(marked)
    (tmp_path / "e.xml").write_text(xml, encoding="utf-8")
    tc6.validate(str(tmp_path / "e.xml"))
    again, _ = import_back(tmp_path / "e.xml", tmp_path / "again.yaml")
    assert shape(again) == shape(g)


def test_a_mark_naming_a_variable_is_refused(tmp_path: Path) -> None:
    """A POU names each variable and action once: a mark that names a variable (case
    ignored) would make the reference name the variable."""
    p = tmp_path / "c.yaml"
    p.write_text("# refused by the export\n"
                 "grafcet: C\ninputs: [Go]\noutputs: [Lamp]\nsteps:\n"
                 "  S0: {initial: true, actions: [\"N (* action lamp *) Lamp := NOT Lamp\"]}\n"
                 "transitions:\n  - {from: S0, to: S0, when: Go}\n", encoding="utf-8")
    with pytest.raises(SourceError) as e:
        export_chart(load_grafcet(str(p)))
    assert "c.yaml:6:" in str(e.value) and "variable 'Lamp'" in str(e.value)


@pytest.mark.parametrize("s1", [
    "N (* action Blink *) Lamp := Lamp",            # another body under the same name
    "N (* action blink *) Lamp := NOT Lamp",        # the same name (IEC ignores case)
])
def test_two_bodies_under_one_action_name_are_refused(tmp_path: Path, s1: str) -> None:
    p = tmp_path / "c.yaml"
    p.write_text("# refused by the export\n"
                 "grafcet: C\ninputs: [Go]\noutputs: [Lamp]\nsteps:\n"
                 "  S0: {initial: true, actions: [\"N (* action Blink *) Lamp := NOT Lamp\"]}\n"
                 f"  S1: {{actions: [\"{s1}\"]}}\n"
                 "transitions:\n  - {from: S0, to: S1, when: Go}\n"
                 "  - {from: S1, to: S0, when: \"NOT Go\"}\n",
                 encoding="utf-8")
    g = load_grafcet(str(p))
    if "blink" in s1:  # the same statements: one action, whatever the case of its mark
        assert _pou_actions(export_chart(g)) == ["Blink"]
        return
    with pytest.raises(SourceError) as e:
        export_chart(g)
    assert "c.yaml:7:" in str(e.value)
    assert "action 'Blink'" in str(e.value) and "S0" in str(e.value)


def test_a_variable_n_leaves_the_qualifier_alone(tmp_path: Path) -> None:
    """Names are spelled as declared, the qualifier is not a name. Before: the variable
    ``n`` made the qualifier ``N`` of every action ``n`` (``n n := n + 1;``)."""
    inline = ('<action localId="0" qualifier="N"><inline><ST><xhtml:p>N := N + 1;</xhtml:p>'
              '</ST></inline></action>')
    (tmp_path / "f.xml").write_text(_file("", {"S1": inline}), encoding="utf-8")
    g, _ = import_back(tmp_path / "f.xml", tmp_path / "a.yaml")
    assert [a.text.strip() for a in g.steps["S1"].actions] == ["N n := n + 1;"]
