"""Loaders' diagnostics: codes, positions, one load that finds every rule error; the error
base class; charts shared within one plant load and never cached across loads."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.engine.simulate import ScanFault
from runtime.errors import Diagnostic, Loc, SoftplcError, SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import PlantLoad, load_plant

RULES = """\
grafcet: T
inputs: [iA, iB]
outputs: [oX, oY]
memory: {sN: 0}
steps:
  gsA: {actions: ["P1 oX", "on ↑iA do oY", "N oX if ↑iB", "N sN := sN + 1"]}
  gsB: {actions: ["P0 oY", oY]}
transitions:
  - {from: gsA, to: gsB, when: iA}
  - {from: gsB, to: gsA, when: "iB + 1 > 1"}
pre:
  - "sN := sN + 0; sN := 2 + iA"
"""

CHART = """\
grafcet: Small
inputs: [iA, iB]
outputs: [oX, oY]
steps:
  gsA: {initial: true}
  gsB: {actions: [oX, oY]}
transitions:
  - {from: gsA, to: gsB, when: iA}
  - {from: gsB, to: gsA, when: "iA'·iB"}
"""


def write(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return str(path)


def test_without_a_list_the_first_rule_error_is_raised_with_its_code(tmp_path: Path) -> None:
    path = write(tmp_path, "t.yaml", RULES)
    with pytest.raises(SourceError) as err:
        load_grafcet(path)
    assert err.value.code == "G105"
    assert err.value.loc == Loc(path, 6, 23)
    assert str(err.value).startswith(f"{path}:6:23: error: expected statements after P1")
    assert str(err.value.diagnostic) == str(err.value)


def test_with_a_list_every_rule_error_is_recorded_and_the_load_goes_on(
        tmp_path: Path) -> None:
    path = write(tmp_path, "t.yaml", RULES)
    found: list[Diagnostic] = []
    g = load_grafcet(path, found)
    assert [(d.code, d.loc.line, d.loc.col) for d in found] == [
        ("G105", 6, 23), ("G105", 6, 39), ("G106", 6, 53), ("G105", 7, 23), ("G101", 5, 1)]
    assert all(isinstance(d, Diagnostic) for d in found)
    # the actions that break a rule are left out, the others kept
    assert [a.text for a in g.actions()] == ["N sN := sN + 1", "oY"]
    # no initial step: the load went on as if the first step were initial
    assert [s.name for s in g.steps.values() if s.initial] == ["gsA"]


def test_other_errors_are_raised_even_with_a_list(tmp_path: Path) -> None:
    path = write(tmp_path, "t.yaml", RULES.replace('oY]}', 'oQ]}'))
    found: list[Diagnostic] = []
    with pytest.raises(SourceError) as err:
        load_grafcet(path, found)
    assert err.value.code == ""
    assert "unknown variable 'oQ'" in err.value.message
    assert [d.code for d in found] == ["G105", "G105", "G106", "G105"]  # met before it


def test_no_step_at_all_stops_the_load_at_g101(tmp_path: Path) -> None:
    path = write(tmp_path, "t.yaml", "grafcet: E\nsteps: {}\n")
    with pytest.raises(SourceError) as err:
        load_grafcet(path, [])
    assert err.value.code == "G101"


def col(text: str, line: int, needle: str) -> int:
    """1-based column of ``needle`` on 1-based line ``line`` of ``text``."""
    return text.splitlines()[line - 1].index(needle) + 1


def test_positions_stay_in_the_model(tmp_path: Path) -> None:
    text = RULES.replace('"P1 oX", ', "").replace('"on ↑iA do oY", ', "").replace(
        '"N oX if ↑iB", ', "").replace('"P0 oY", ', "").replace("gsA: {", "gsA: {initial: true, ")
    path = write(tmp_path, "t.yaml", text)
    g = load_grafcet(path)
    act = g.steps["gsA"].actions[0]
    assert act.text == "N sN := sN + 1" and act.at(2) == Loc(path, 6, col(text, 6, "sN :="))
    t = g.transitions[1]
    assert t.at(5) == Loc(path, 10, col(text, 10, "1 > 1"))  # inside the quoted condition
    assert t.source_locs == [Loc(path, 10, col(text, 10, "gsB,"))]
    assert t.target_locs == [Loc(path, 10, col(text, 10, "gsA,"))]
    st = g.pre[1]
    assert st.text == "sN := 2 + iA" and st.at(st.node.start) == Loc(path, 12, col(
        text, 12, "sN := 2"))


PLANT = """\
drivers:
  sim: {type: sim}
instances:
  a:
    grafcet: small.yaml
    inputs: {iA: sim.I0}
    outputs: {oX: sim.Q0, oY: sim.Q1}
  b:
    grafcet: small.yaml
    inputs: {iA: sim.I1, iB: nowhere.I0}
    outputs: {oX: sim.Q2, oY: sim.Q1}
"""


def test_plant_binding_errors_are_all_recorded_in_one_load(tmp_path: Path) -> None:
    write(tmp_path, "small.yaml", CHART)
    path = write(tmp_path, "plant.yaml", PLANT)
    with pytest.raises(SourceError) as err:
        load_plant(path)
    assert (err.value.code, err.value.loc.line) == ("G301", 6)
    load = PlantLoad([])
    load_plant(path, load)
    assert load.diagnostics is not None
    assert [(d.code, d.loc.line) for d in load.diagnostics] == [
        ("G301", 6), ("", 10), ("G302", 11)]
    assert "unknown driver or instance 'nowhere'" in load.diagnostics[1].message
    assert load.chart_files == [str(tmp_path / "small.yaml")]


def test_an_instance_that_does_not_load_is_left_out_and_the_others_checked(
        tmp_path: Path) -> None:
    write(tmp_path, "small.yaml", CHART)
    path = write(tmp_path, "plant.yaml", """\
drivers: {sim: {type: sim}}
instances:
  a: {grafcet: small.yaml, inputs: {iA: sim.I0}, outputs: {oX: sim.Q0, oY: sim.Q1}}
  b: {grafcet: missing.yaml}
  c: {grafcet: small.yaml, colour: red, inputs: [iA], outputs: {oX: sim.Q2, oY: sim.Q3}}
""")
    load = PlantLoad([])
    p = load_plant(path, load)
    assert load.diagnostics is not None
    assert [(d.code, d.loc.line, d.message.split(":")[0]) for d in load.diagnostics] == [
        ("G301", 3, "instance 'a' leaves input 'iB' of grafcet Small unbound"),
        ("", 4, "grafcet file not found"),
        ("", 5, "unknown key 'colour' in instance 'c'"),
        ("", 5, "expected a mapping of inputs, found a list"),
        ("G301", 5, "instance 'c' leaves input 'iA' of grafcet Small unbound"),
        ("G301", 5, "instance 'c' leaves input 'iB' of grafcet Small unbound")]
    assert list(p.instances) == ["a", "c"]


def test_a_chart_error_in_a_plant_is_recorded_and_its_instance_left_out(
        tmp_path: Path) -> None:
    write(tmp_path, "small.yaml", CHART)
    write(tmp_path, "bad.yaml", CHART.replace("actions: [oX", 'actions: ["P1 oX"'))
    path = write(tmp_path, "plant.yaml", PLANT.replace("grafcet: small.yaml\n    inputs: {iA: "
                                                       "sim.I1", "grafcet: bad.yaml\n    "
                                                       "inputs: {iA: sim.I1"))
    load = PlantLoad([])
    p = load_plant(path, load)
    assert load.diagnostics is not None
    first = load.diagnostics[1]
    assert first.code == "G105" and first.loc.file.endswith("bad.yaml")
    assert list(p.instances) == ["a"]


def test_instances_of_one_plant_share_their_chart_and_loads_share_nothing(
        tmp_path: Path) -> None:
    write(tmp_path, "small.yaml", CHART)
    path = write(tmp_path, "plant.yaml", """\
        drivers: {sim: {type: sim}}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.Q0, oY: sim.Q1}
          b:
            grafcet: ./small.yaml
            inputs: {iA: sim.I2, iB: sim.I3}
            outputs: {oX: sim.Q2, oY: sim.Q3}
        """.replace("        ", ""))
    first, second = load_plant(path), load_plant(path)
    assert first.instances["a"].grafcet is first.instances["b"].grafcet
    assert first.instances["a"].grafcet is not second.instances["a"].grafcet
    chart = str(tmp_path / "small.yaml")
    assert load_grafcet(chart) is not load_grafcet(chart)


def test_one_base_class_for_the_project_errors() -> None:
    assert issubclass(SourceError, SoftplcError)
    assert issubclass(ScanFault, SoftplcError)
    err = SourceError(Loc("f.yaml", 3, 7), "expected x, found y")
    assert str(err) == "f.yaml:3:7: error: expected x, found y" and err.code == ""
