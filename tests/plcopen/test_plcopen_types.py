"""The IEC 61131-3 type a PLCopen file gives a variable (INT, DINT, REAL ...) survives
import and export (the chart's ``iec_type:``), and changes nothing the runtime computes;
located variables are located in the plant skeleton (``at:``), and the export of the plant
writes them back (the export of a chart has no place for them)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.engine.simulate import Simulation
from runtime.errors import SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.plcopen.commands import chart_text
from runtime.plcopen.export import export_chart
from runtime.plcopen.importer import import_file
from runtime.plcopen.yamlout import binding_at
from tests.plcopen.plcopenkit import DATA, shape

SOURCE = DATA / "typed_located.xml"
#: every variable of typed_located.xml and the type the file declares
DECLARED = {"Level": "INT", "Flow": "REAL", "Go": "BOOL", "Setpoint": "DINT", "Total": "LINT",
            "Valve": "BOOL", "Count": "UINT", "Gain": "LREAL", "Big": "INT"}


def declared(xml: str) -> dict[str, str]:
    """Each variable of an exported project's interface -> the type it declares."""
    return dict(re.findall(r'<variable name="(\w+)">\s*<type>\s*<(\w+)/>', xml))


def _chart(path: Path, out: Path) -> str:
    """The text of the chart softplc import writes for the first POU of ``path`` in
    ``out``, without its header comment (which names the source file)."""
    result = import_file(str(path))
    text = chart_text(str(path), result.charts[0])
    out.write_text(text, encoding="utf-8")
    return "".join(line for line in text.splitlines(keepends=True)
                   if not line.startswith("#"))


def test_the_iec_type_survives_import_then_export(tmp_path: Path, tc6: Any) -> None:
    """An INT stays INT (not LINT), a REAL REAL, a DINT DINT, a UINT UINT: the export of the
    imported chart declares the types the file declared, and is valid against the schema.
    (Before ``iec_type:`` every int exported as LINT and every real as LREAL.)"""
    first = tmp_path / "Filler.yaml"
    _chart(SOURCE, first)
    xml = export_chart(load_grafcet(str(first)))
    assert declared(xml) == DECLARED
    exported = tmp_path / "Filler.xml"
    exported.write_text(xml, encoding="utf-8")
    tc6.validate(str(exported))


def test_import_export_import_gives_the_same_chart(tmp_path: Path) -> None:
    """export(import(file)), imported again, is the same chart file, iec_type included, and
    ``softplc diff`` says no change."""
    first = tmp_path / "a" / "Filler.yaml"
    first.parent.mkdir()
    text = _chart(SOURCE, first)
    assert "iec_type: INT" in text and "iec_type: UINT" in text
    assert "iec_type: LINT" not in text and "iec_type: LREAL" not in text  # the defaults
    xml = tmp_path / "again.xml"
    xml.write_text(export_chart(load_grafcet(str(first))), encoding="utf-8")
    second = tmp_path / "b" / "Filler.yaml"
    second.parent.mkdir()
    assert _chart(xml, second) == text
    assert shape(load_grafcet(str(second))) == shape(load_grafcet(str(first)))
    assert main(["diff", str(first), str(second)]) == 0


def test_a_chart_without_iec_type_exports_lint_and_lreal(tmp_path: Path) -> None:
    p = tmp_path / "plain.yaml"
    p.write_text("grafcet: Plain\ninputs: [{n: int}, {r: real}, b, {t: time}]\n"
                 "memory: {m: 0, f: 0.5}\nsteps: {S0: {initial: true}}\ntransitions: []\n",
                 encoding="utf-8")
    assert declared(export_chart(load_grafcet(str(p)))) == {
        "n": "LINT", "r": "LREAL", "b": "BOOL", "t": "TIME", "m": "LINT", "f": "LREAL"}


@pytest.mark.parametrize("decl, message", [
    ("inputs: [{n: {type: real, iec_type: INT}}]",
     "4:37: iec_type INT does not fit a variable of type real: expected one of LREAL, REAL"),
    ("memory: {m: {init: 0, iec_type: REAL}}",
     "4:33: iec_type REAL does not fit a variable of type int: expected one of LINT, SINT,"),
    ("outputs: [{o: {type: bool, iec_type: INT}}]",
     "4:38: iec_type INT does not fit a variable of type bool: expected one of BOOL"),
    ("memory: {m: {init: 0, iec_type: Int}}",
     "4:33: iec_type Int does not fit a variable of type int: expected one of LINT,"),
])
def test_an_iec_type_of_another_type_is_refused_at_its_place(
        tmp_path: Path, decl: str, message: str) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text(f"# a chart\ngrafcet: Bad\n\n{decl}\nsteps: {{S0: {{initial: true}}}}\n"
                 "transitions: []\n", encoding="utf-8")
    with pytest.raises(SourceError) as e:
        load_grafcet(str(p))
    where, text = message.split(": ", 1)
    assert f"bad.yaml:{where}: error: {text}" in str(e.value)


def test_an_int_is_not_bounded_by_its_iec_type(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """``Big`` is INT in the file (-32768..32767 in IEC 61131-3); the runtime computes it as
    the language's int, without bounds or wrap-around: 30000 added in each scan of Fill
    reaches 60000, 90000 ... (docs/plcopen.md says so)."""
    out = tmp_path / "out"
    assert main(["import", str(SOURCE), "-o", str(out)]) == 0
    capsys.readouterr()
    script = tmp_path / "script.yaml"
    script.write_text("duration: 200ms\nset:\n  - {at: 100ms, fill.Go: 1}\n", encoding="utf-8")
    rows = list(Simulation(str(out / "plant.yaml"), str(script)).run(trace=True))
    fill = [r for r in rows if r["fill.Fill.X"]]
    assert fill and fill[0]["t_ms"] >= 100
    assert [r["fill.Big"] for r in fill] == [30000 * (i + 1) for i in range(len(fill))]
    assert fill[-1]["fill.Big"] > 32767


def test_a_located_variable_is_located_in_the_plant(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """%IX0.3 and %QX0.1 are the bindings' ``at:`` in the plant skeleton (before: a comment
    beside the binding, which an export of the plant could not write back); the export of
    the chart alone has no place for them (an address belongs to a binding)."""
    out = tmp_path / "out"
    assert main(["import", str(SOURCE), "-o", str(out)]) == 0
    capsys.readouterr()
    plant = (out / "plant.yaml").read_text(encoding="utf-8")
    assert 'Go: {from: sim.I0, at: "%IX0.3"}\n' in plant
    assert 'Valve: {from: sim.Q0, at: "%QX0.1"}\n' in plant
    assert "address=" not in export_chart(load_grafcet(str(out / "Filler.yaml")))
    p = tmp_path / "p.xml"
    assert main(["export", str(out / "plant.yaml"), "-o", str(p)]) == 0
    capsys.readouterr()
    text = p.read_text(encoding="utf-8")
    assert 'address="%IX0.3"' in text and 'address="%QX0.1"' in text


@pytest.mark.parametrize(("address", "typ", "area", "said"), [
    ("%IX0.3", "bool", "I", ("", "%IX0.3")),
    ("%iw2", "int", "I", ("", "%IW2")),
    ("%QD4", "real", "Q", ("", "%QD4")),
    ("%MW4", "int", "I", ("%MW4 in the PLCopen file", "")),     # not an input's area
    ("%IW2", "bool", "I", ("%IW2 in the PLCopen file", "")),    # a word for a bit
    ("%QX0.1", "bool", "I", ("%QX0.1 in the PLCopen file", "")),  # an output's, on an input
    ("%IX1.2.3", "bool", "I", ("%IX1.2.3 in the PLCopen file", "")),  # no form of at:
])
def test_an_address_a_binding_can_carry_is_its_at(address: str, typ: str, area: str,
                                                  said: tuple[str, str]) -> None:
    """The rule of the plant skeleton: the address is the binding's ``at:`` when the
    binding's checks accept it, else a comment beside it (as before)."""
    assert binding_at(f"{address} in the PLCopen file", address, typ, area) == said
