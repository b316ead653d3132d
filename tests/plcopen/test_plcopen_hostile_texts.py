"""No text of a PLCopen file runs as code: a project whose every text (ST comments in
conditions and actions, documentation, softplc's additional data, the pre and post
equations) carries a line break of every kind (as XML character references: ``&#13;``
survives the XML parser's line-end normalisation) and a Python payload either imports
(``softplc import``) into charts and a plant that compile to the very programs the same
project compiles to without the payload, or is refused with one ``FILE:LINE:COL: error:``
line; the payload never runs, neither in the charts' scans nor in the plant's cycle."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.cli import main
from runtime.compiler.codegen import compile_grafcet
from runtime.engine.plant import Plant
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import load_plant
from runtime.plcopen.export import export_chart
from tests.engine.test_hostile_texts import SEPARATORS, plant_shapes, shape

MS = 1_000_000

#: the chart exported as the project the texts are put in: MARK* where each text goes
CHART = """\
grafcet: Hostile
description: MARKD0
inputs: [iA, {iB: {type: bool, description: MARKD1}}]
outputs: [oB, oC]
memory:
  sX: {init: 0, description: MARKD2}
pre:
  - "tQ := iA (* MARKC0 *)"
steps:
  s1:
    initial: true
    description: MARKD3
    actions: ["P1 sX := sX + 1 (* MARKC1 *)", "N oC if iB // MARKC2"]
  s2: {description: MARKD4, actions: [oB]}
transitions:
  - {from: s1, to: s2, when: "iA (* MARKC3 *) AND NOT iB"}
  - {from: s2, to: s1, when: "NOT iA // MARKC4"}
post:
  - "sX := sX (* MARKC5 *)"
"""
#: the ST bodies of the project (written by the export as CDATA) and the comment each gets
ST_BODIES = {"<![CDATA[iA AND NOT iB]]>": "iA (* {} *) AND NOT iB",
             "<![CDATA[NOT iA]]>": "NOT iA // {}",
             "<![CDATA[sX := sX + 1;]]>": "sX := sX + 1; (* {} *)",
             "<![CDATA[oC if iB]]>": "oC if iB (* {} *)"}
SLOTS = [*(f"MARKD{k}" for k in range(5)), *(f"MARKC{k}" for k in range(6)), *ST_BODIES]


def xml_text(text: str) -> str:
    """``text`` as XML character data: markup escaped, every character that the parser
    would normalise or refuse written as a character reference."""
    out = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return "".join(c if c.isprintable() else f"&#{ord(c)};" for c in out)


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory) -> str:
    chart = tmp_path_factory.mktemp("template") / "hostile.yaml"
    chart.write_text(CHART, encoding="utf-8")
    return export_chart(load_grafcet(str(chart)))


def project(template: str, texts: dict[str, str], own_data: bool) -> str:
    """The project with ``texts`` (slot -> text) and "x" in every other slot; without
    ``own_data``, softplc's additional data removed (as an editor writes the file: the
    ST bodies are what the import reads)."""
    xml = template
    for slot, around in ST_BODIES.items():
        xml = xml.replace(slot, xml_text(around.format(texts.get(slot, "x"))))
    xml = re.sub(r"MARK[CD]\d", lambda m: xml_text(texts.get(m.group(0), "x")), xml)
    if not own_data:
        xml = re.sub(r"<addData>.*?</addData>", "", xml, flags=re.S)
    return xml


_REFUSAL = re.compile(r"^\S+:\d+:\d+: error: [^\n]+\n$")


def imported(tmp: Path, xml: str, capsys: pytest.CaptureFixture[str]) \
        -> tuple[list[str], list[str]] | str:
    """``softplc import`` of ``xml``, then its charts compiled and its plant run: the
    shapes of the programs, or the one-line refusal."""
    src, out = tmp / "project.xml", tmp / "out"
    src.write_text(xml, encoding="utf-8")
    capsys.readouterr()
    status = main(["import", str(src), "-o", str(out), "--force"])
    err = capsys.readouterr().err
    if status != 0:
        assert status == 2 and _REFUSAL.match(err), err
        return err
    charts = sorted(p for p in out.glob("*.yaml") if p.name != "plant.yaml")
    programs = [shape(compile_grafcet(load_grafcet(str(p))).source) for p in charts]
    plant = Plant(load_plant(str(out / "plant.yaml")), sim=True)
    plant.open()
    sim = plant.drivers["sim"]
    for k, a in enumerate([0, 0, 1, 1, 0, 0, 1, 0]):
        for point in list(sim.inputs):
            sim.inputs[point] = a
        plant.cycle(k * 10 * MS)
    plant.close()
    return programs, plant_shapes(plant)


def payload(marker: Path, sep: str, indent: int) -> str:
    pad = " " * indent
    return f"{sep}{pad}open({str(marker)!r}, 'w').write('ran'){sep}{pad}#"


@pytest.mark.parametrize("own_data", [True, False], ids=["softplc's data", "as an editor"])
@pytest.mark.parametrize("sep", SEPARATORS, ids=[repr(s) for s in SEPARATORS])
def test_every_text_of_a_project_holding_a_payload_never_runs(
        tmp_path: Path, template: str, capsys: pytest.CaptureFixture[str], sep: str,
        own_data: bool) -> None:
    clean = imported(tmp_path, project(template, {}, own_data), capsys)
    assert not isinstance(clean, str), clean
    marker = tmp_path / "ran"
    for slot in SLOTS:
        for indent in (0, 12, 16, 20):
            texts = {slot: payload(marker, sep, indent)}
            out = imported(tmp_path, project(template, texts, own_data), capsys)
            assert not marker.exists(), f"the payload in {slot} ran at indent {indent}"
            if not isinstance(out, str):
                assert out == clean, f"{slot} at indent {indent} changed the program"


@settings(max_examples=60, deadline=None, suppress_health_check=[
    HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.dictionaries(st.sampled_from(SLOTS), st.tuples(
    st.sampled_from(SEPARATORS), st.integers(0, 24)), min_size=1), st.booleans())
def test_any_mix_of_hostile_project_texts_never_runs(
        tmp_path: Path, template: str, capsys: pytest.CaptureFixture[str],
        texts: dict[str, tuple[str, int]], own_data: bool) -> None:
    marker = tmp_path / "ran"
    marker.unlink(missing_ok=True)
    clean = imported(tmp_path, project(template, {}, own_data), capsys)
    hostile = {k: payload(marker, sep, indent) for k, (sep, indent) in texts.items()}
    out = imported(tmp_path, project(template, hostile, own_data), capsys)
    assert not marker.exists()
    if not isinstance(out, str):
        assert out == clean
