"""The I/O list (runtime/language/iolist.py): what the plant file says of each signal,
read back through the one API every reader uses, and ``softplc iolist``."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import pytest

from runtime.cli import main
from runtime.errors import SourceError
from runtime.language.iolist import IOList, Meaning
from runtime.language.plantfile import load_plant
from runtime.language.units import UNITS, find_unit

ROOT = Path(__file__).resolve().parents[2]
DRAWER = ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"

CHART = """\
grafcet: Tank
description: A tank filled to a level
inputs:
  - {iNivel: {type: real, description: level in the tank}}
  - {iCaudal: int}
  - iLleno
outputs: [oBomba]
memory:
  sConsigna: {init: 50.0, description: level set point}
  sEspera: 2s
steps:
  gsVacio: {initial: true, description: filling}
  gsLleno: {max: 10s}
transitions:
  - {from: gsVacio, to: gsLleno, when: "iNivel >= sConsigna"}
  - {from: gsLleno, to: gsVacio, when: "iNivel < 10.0"}
post:
  - oBomba := gsVacio.X
"""


def plant(tmp: Path, bindings: str) -> Path:
    (tmp / "tank.yaml").write_text(CHART, encoding="utf-8")
    path = tmp / "plant.yaml"
    path.write_text(
        "drivers:\n  io: {type: sim}\ninstances:\n  t1:\n    grafcet: tank.yaml\n"
        "    description: Depósito 1\n" + bindings, encoding="utf-8")
    return path


GOOD = """\
    inputs:
      iNivel:  {from: io.level, unit: cm, range: [0, 150], description: sensor LT1 (4-20 mA)}
      iCaudal: {from: io.flow, unit: l/min, range: [0, 80]}
      iLleno:  {from: io.I3, invert: true, description: 'LSH1, NC'}
    outputs:
      oBomba:  {from: io.Q0, description: bomba P1}
"""


def test_the_list_and_the_meaning_of_every_kind_of_name(tmp_path: Path) -> None:
    iol = IOList(load_plant(str(plant(tmp_path, GOOD))))
    cm, lmin, ms = UNITS["CMT"], UNITS["L2"], UNITS["C26"]
    assert [(r.signal, r.direction, r.source, r.invert) for r in iol.rows] == [
        ("t1.iNivel", "in", "io.level", False), ("t1.iCaudal", "in", "io.flow", False),
        ("t1.iLleno", "in", "io.I3", True), ("t1.oBomba", "out", "io.Q0", False)]
    assert iol.meaning("t1.iNivel") == Meaning("sensor LT1 (4-20 mA)", cm, (0.0, 150.0))
    # no description in the binding: the chart's; none in either: nothing
    assert iol.meaning("t1.iCaudal") == Meaning("", lmin, (0.0, 80.0))
    assert iol.meaning("t1.iLleno") == Meaning("LSH1, NC")
    assert iol.meaning("t1") == Meaning("Depósito 1")
    assert iol.meaning("t1.sConsigna") == Meaning("level set point")
    assert iol.meaning("t1.sEspera") == Meaning("", ms)  # a time: ms
    assert iol.meaning("t1.gsVacio") == iol.meaning("t1.gsVacio.X") == Meaning("filling")
    assert iol.meaning("t1.gsVacio.T") == Meaning("filling", ms)
    assert iol.meaning("t1.SFCError").description.startswith("set by a step over its max")
    assert iol.meaning("io.level") == Meaning("-> t1.iNivel: sensor LT1 (4-20 mA)", cm,
                                              (0.0, 150.0))
    assert iol.meaning("io.I3").description == "-> t1.iLleno (NC, inverted): LSH1, NC"
    assert iol.meaning("io.Q0").description == "<- t1.oBomba: bomba P1"
    assert iol.meaning("io.ok").description == "true while the driver is healthy"
    assert iol.meaning("t1.nothing") == iol.meaning("nowhere.x") == Meaning()
    assert [r.signal for r in iol.bound_to("io.level")] == ["t1.iNivel"]


def test_a_chart_without_bindings_descriptions_falls_back_on_the_chart(
        tmp_path: Path) -> None:
    iol = IOList(load_plant(str(plant(tmp_path, (
        "    inputs: {iNivel: io.level, iCaudal: io.flow, iLleno: io.I3}\n"
        "    outputs: {oBomba: io.Q0}\n")))))
    assert iol.meaning("t1.iNivel") == Meaning("level in the tank")
    assert iol.meaning("t1.oBomba") == Meaning()


@pytest.mark.parametrize(("binding", "col", "words"), [
    ("{from: io.level, unit: CELSIUS}", 38, "unknown unit 'CELSIUS'"),
    # letter case and a plural first, each candidate with what it measures (a level is a
    # length: 'cms' suggested 'ms' alone, 'degc' the angle 'deg')
    ("{from: io.level, unit: degc}", 38, "(did you mean 'degC' (degree Celsius, a "
                                         "temperature) or 'deg' (degree (angle), an angle)"),
    ("{from: io.level, unit: cms}", 38, "(did you mean 'cm' (centimetre, a length) or 'ms' "
                                        "(millisecond, a time)"),
    ("{from: io.level, range: [10, 0]}", 39, "range: expected low < high, found [10, 0]"),
    ("{from: io.level, range: [0, .inf]}", 39, "two finite numbers"),
    ("{from: io.level, range: 5}", 39, "expected [low, high]"),
    ("{from: io.level, description: [a]}", 45, "expected a text for description"),
    ("{from: io.level, colour: red}", 32, "unknown key 'colour' in the binding of 'iNivel'"),
])
def test_bad_entries_are_placed(tmp_path: Path, binding: str, col: int, words: str) -> None:
    path = plant(tmp_path, f"    inputs:\n      iNivel: {binding}\n"
                           "      iCaudal: io.flow\n      iLleno: io.I3\n"
                           "    outputs: {oBomba: io.Q0}\n")
    with pytest.raises(SourceError) as err:
        load_plant(str(path))
    assert (err.value.loc.line, err.value.loc.col) == (8, col), err.value
    assert words in err.value.message


@pytest.mark.parametrize(("line", "words"), [
    ("      iLleno: {from: io.I3, unit: cm}\n",
     "unit applies to int and real signals only: 'iLleno' is a bool"),
    ("      iLleno: {from: io.I3, range: [0, 1]}\n",
     "range applies to int and real signals only: 'iLleno' is a bool"),
])
def test_a_unit_or_range_belongs_to_numbers(tmp_path: Path, line: str, words: str) -> None:
    path = plant(tmp_path, "    inputs:\n      iNivel: io.level\n      iCaudal: io.flow\n"
                           f"{line}    outputs: {{oBomba: io.Q0}}\n")
    with pytest.raises(SourceError, match=words):
        load_plant(str(path))


def test_a_description_is_one_short_line(tmp_path: Path) -> None:
    long = "x" * 201
    path = plant(tmp_path, f"    inputs:\n      iNivel: {{from: io.level, description: {long}}}\n"
                           "      iCaudal: io.flow\n      iLleno: io.I3\n"
                           "    outputs: {oBomba: io.Q0}\n")
    with pytest.raises(SourceError, match="at most 200 characters, found 201"):
        load_plant(str(path))
    (tmp_path / "tank.yaml").write_text(CHART.replace(
        "description: filling}", 'description: "two\\nlines"}'), encoding="utf-8")
    with pytest.raises(SourceError, match="one line of text"):
        load_plant(str(plant_keep_chart(tmp_path)))


def plant_keep_chart(tmp: Path) -> Path:
    path = tmp / "plant.yaml"
    path.write_text("drivers:\n  io: {type: sim}\ninstances:\n  t1:\n    grafcet: tank.yaml\n"
                    + GOOD, encoding="utf-8")
    return path


def test_units_by_code_symbol_or_ascii() -> None:
    assert find_unit("CEL") is find_unit("°C") is find_unit("degC") is UNITS["CEL"]
    assert find_unit("m³/h") is find_unit("m3/h") is UNITS["MQH"]
    assert find_unit("celsius") is None
    # OPC UA's UnitId (Part 8, 5.6.3), checked against the OPC Foundation's table
    assert (UNITS["CEL"].unit_id, UNITS["P1"].unit_id, UNITS["C26"].unit_id) == (
        4408652, 20529, 4403766)


def test_the_drawer_tester_carries_its_io_list_in_spanish() -> None:
    iol = IOList(load_plant(str(DRAWER)))
    assert len(iol.rows) == 16
    assert iol.meaning("tester1.iParo") == Meaning("Pulsador de paro SJP (NC)")
    assert iol.meaning("tester2.oAbrir") == Meaning("Contactor QAA, abrir el cajón")
    assert iol.meaning("tester1").description == "Banco de ensayo de guías de cajón 1"
    assert all(r.meaning.description for r in iol.rows)


@pytest.mark.parametrize("plant", sorted(ROOT.glob("configs/*/plant*.yaml")),
                         ids=lambda p: p.parent.name)
def test_every_example_plant_carries_its_io_list(plant: Path) -> None:
    """Issue 29: each example plant says what each of its signals is, and each instance
    what it is."""
    pdef = load_plant(str(plant))
    iol = IOList(pdef)
    assert iol.rows
    assert [r.signal for r in iol.rows if not r.meaning.description] == []
    assert [n for n in pdef.instances if not iol.meaning(n).description] == []


def test_softplc_iolist_prints_the_table_and_the_csv(
        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["iolist", str(DRAWER)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["signal", "point", "NC", "type", "description", "unit",
                                "range"]
    assert lines[1].split() == ["tester1.iParo", "sim.I0", "NC", "input", "bool",
                                "Pulsador", "de", "paro", "SJP", "(NC)"]
    # in the order of the terminals: the inputs I0..I7, then the outputs Q0..Q7
    assert [ln.split()[1] for ln in lines[1:]] == [f"sim.I{k}" for k in range(8)] + [
        f"sim.Q{k}" for k in range(8)]
    assert main(["iolist", str(DRAWER), "--csv"]) == 0
    rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert rows[0] == ["signal", "point", "NC", "type", "description", "unit", "unit code",
                       "low", "high"]
    assert rows[3] == ["tester1.iAbierto", "sim.I2", "", "input bool",
                       "Final de carrera BGA, cajón abierto", "", "", "", ""]


def test_softplc_iolist_with_units_and_ranges(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["iolist", str(plant(tmp_path, GOOD)), "--csv"]) == 0
    rows = list(csv.reader(io.StringIO(capsys.readouterr().out)))
    assert rows[1:] == [
        ["t1.iLleno", "io.I3", "NC", "input bool", "LSH1, NC", "", "", "", ""],
        ["t1.iCaudal", "io.flow", "", "input int", "", "l/min", "L2", "0", "80"],
        ["t1.iNivel", "io.level", "", "input real", "sensor LT1 (4-20 mA)", "cm", "CMT",
         "0", "150"],
        ["t1.oBomba", "io.Q0", "", "output bool", "bomba P1", "", "", "", ""]]
    bad = tmp_path / "bad.yaml"
    bad.write_text("instances: {}\nnonsense: 1\n", encoding="utf-8")
    assert main(["iolist", str(bad)]) == 2
    assert "unknown key 'nonsense'" in capsys.readouterr().err


def test_an_output_may_be_bound_with_to(tmp_path: Path) -> None:
    """``oBomba: {to: io.Q0}``: an output's value goes to its point (``from:`` stays
    accepted, as every plant before wrote it)."""
    iol = IOList(load_plant(str(plant(tmp_path, GOOD.replace(
        "oBomba:  {from: io.Q0,", "oBomba:  {to: io.Q0,")))))
    assert [(r.signal, r.direction, r.source) for r in iol.rows][-1] == (
        "t1.oBomba", "out", "io.Q0")
    assert iol.meaning("io.Q0").description == "<- t1.oBomba: bomba P1"


@pytest.mark.parametrize(("bindings", "col", "words"), [
    (GOOD.replace("iNivel:  {from: io.level,", "iNivel:  {to: io.level,"), 17,
     "'to:' binds an output (its value goes to the point): an input's value comes from its "
     "point: write 'from: io.level'"),
    (GOOD.replace("oBomba:  {from: io.Q0,", "oBomba:  {from: io.Q0, to: io.Q1,"), 30,
     "the binding of 'oBomba' names its point twice ('from:' and 'to:'): keep one"),
    (GOOD.replace("oBomba:  {from: io.Q0,", "oBomba:  {"), 16,
     "binding of 'oBomba' needs 'to: driver.point' (or 'from:')"),
])
def test_to_binds_outputs_only_and_once(tmp_path: Path, bindings: str, col: int,
                                        words: str) -> None:
    with pytest.raises(SourceError) as err:
        load_plant(str(plant(tmp_path, bindings)))
    assert err.value.loc.col == col, err.value
    assert words in err.value.message, err.value
