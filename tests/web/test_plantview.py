"""The page's I/O list carries each signal's meaning from the plant's I/O list (issue 29)."""

from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

from runtime.language.plantfile import load_plant
from runtime.web.plantview import chart_of, describe

ROOT = Path(__file__).resolve().parents[2]


def test_the_io_list_of_the_page_carries_the_descriptions_of_the_plant() -> None:
    """Before, the description column was empty for every signal."""
    plant = describe(load_plant(str(ROOT / "configs/drawer_tester/plant_sim.yaml")))
    rows = {row[0]: row for inst in plant["instances"] for row in inst["io"]}
    assert rows["tester1.iParo"][2] == "sim.I0 (inverted)"
    assert rows["tester1.iParo"][3] == "Pulsador de paro SJP (NC)"
    assert rows["tester1.oAbrir"][3] == "Contactor QAA, abrir el cajón"
    described = [r for r in rows.values() if r[1] in ("in", "out")]
    assert described and all(r[3] for r in described), [r for r in described if not r[3]]


def test_each_condition_is_drawn_as_the_why_list_says_it(tmp_path: Path) -> None:
    """A chart written in ST (a drill of the course, as a PLCopen import writes them): the
    page's drawing showed '↑iMarcha·iPieza·tParo\'' above a "why" list saying 'RE iMarcha
    AND iPieza AND NOT tParo'. Both say it as the file wrote it."""
    shutil.copy(ROOT / "tests/drawing/charts/taladro.yaml", tmp_path / "taladro.yaml")
    (tmp_path / "plant.yaml").write_text(
        "drivers: {io: {type: sim}}\ninstances:\n  d:\n    grafcet: taladro.yaml\n"
        "    inputs: {iMarcha: io.I0, iParo: io.I1, iArriba: io.I2, iAbajo: io.I3, "
        "iPieza: io.I4, iPuerta: io.I5}\n"
        "    outputs: {oBajar: io.Q0, oSubir: io.Q1, oMotor: io.Q2, oPiloto: io.Q3, "
        "oRefrigerar: io.Q4}\n", encoding="utf-8")
    pdef = load_plant(str(tmp_path / "plant.yaml"))
    (inst,) = describe(pdef)["instances"]
    svg = chart_of(pdef, "d")
    assert svg is not None
    ns = "{http://www.w3.org/2000/svg}"
    drawn = {g.get("data-transition"): " ".join("".join(t.itertext()) for t in g.iter(f"{ns}text")
                                                if t.get("class") == "condition")
             for g in ET.fromstring(svg).iter(f"{ns}g") if g.get("class") == "transition-group"}
    assert {str(k): text for k, text in inst["transitions"]} == drawn
