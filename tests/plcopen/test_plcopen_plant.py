"""``softplc export PLANT.yaml``: the plant's charts as SFC function blocks, a program in
FBD calling one instance per instance of the plant, its variables located at the bindings'
addresses and documented with their descriptions; importing that project gives the plant
back (docs/plcopen.md, "Exporting a plant")."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.errors import SourceError
from runtime.language.filekind import file_kind
from runtime.language.model import Binding, PlantDef
from runtime.language.plantfile import load_plant
from runtime.plcopen.plantexport import export_plant
from tests.plcopen.plcopenkit import ROOT, shape

FEEDER = """\
grafcet: Feeder
inputs: [{Start: {description: start button}}, {Level: {type: int, iec_type: INT}}]
outputs: [Motor, Busy]
steps:
  Idle: {initial: true}
  Feed: {actions: [Motor, Busy]}
transitions:
  - {from: Idle, to: Feed, when: Start}
  - {from: Feed, to: Idle, when: Level > 10}
"""

PACKER = """\
grafcet: Packer
inputs: [Ready, Stop]
outputs: [Lamp]
steps:
  Wait: {initial: true}
  Pack: {actions: [Lamp]}
transitions:
  - {from: Wait, to: Pack, when: Ready AND NOT Stop}
  - {from: Pack, to: Wait, when: NOT Ready}
"""

PLANT = """\
plc:
  cycle: 20ms
drivers:
  sim: {type: sim}
instances:
  feeder:
    description: the feeder of line 2
    grafcet: feeder.yaml
    inputs:
      Start: {from: sim.I0, at: '%IX0.3', description: green start button}
      Level: {from: sim.IR0, at: '%IW2', description: tank level}
    outputs:
      Motor: {to: sim.Q0, at: '%QX0.1', description: feed motor}
      Busy: sim.Q1
  packer:
    grafcet: packer.yaml
    inputs:
      Ready: {from: feeder.Busy}
      Stop: {from: sim.I1, invert: true}
    outputs:
      Lamp: sim.Q2
"""


def _plant(d: Path) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "feeder.yaml").write_text(FEEDER, encoding="utf-8")
    (d / "packer.yaml").write_text(PACKER, encoding="utf-8")
    (d / "plant.yaml").write_text(PLANT, encoding="utf-8")
    return d / "plant.yaml"


def _binding(b: Binding) -> tuple[Any, ...]:
    return (b.signal, b.source, b.invert, b.at, b.description)


def _said(p: PlantDef) -> list[Any]:
    """What a plant says of its instances: name, chart, every binding; and its cycle."""
    return [p.cycle_ns] + [
        (i.name, i.description, shape(i.grafcet), [_binding(b) for b in i.inputs.values()],
         [_binding(b) for b in i.outputs.values()]) for i in p.instances.values()]


def test_a_plant_exports_as_function_blocks_called_by_a_program(
        tmp_path: Path, tc6: Any, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: 'softplc export' read a chart only (a plant file was refused)."""
    plant = _plant(tmp_path / "p")
    xml = tmp_path / "plant.xml"
    assert main(["export", str(plant), "-o", str(xml), "--layout", "python"]) == 0
    capsys.readouterr()
    tc6.validate(str(xml))
    text = xml.read_text(encoding="utf-8")
    assert re.findall(r'<pou name="(\w+)" pouType="(\w+)"', text) == [
        ("Feeder", "functionBlock"), ("Packer", "functionBlock"), ("Plant", "program")]
    assert re.findall(r'<block [^>]*typeName="(\w+)" instanceName="(\w+)"', text) == [
        ("Feeder", "feeder"), ("Packer", "packer")]
    assert '<variable name="sim_I0" address="%IX0.3">' in text
    assert '<variable name="sim_IR0" address="%IW2">' in text
    assert '<variable name="sim_Q0" address="%QX0.1">' in text
    assert "green start button" in text and "feed motor" in text
    assert 'interval="T#20ms"' in text


def test_importing_the_export_gives_the_plant_back(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The same instances, charts, bindings (points, links, inversions, addresses,
    descriptions) and cycle."""
    plant = _plant(tmp_path / "p")
    xml = tmp_path / "plant.xml"
    assert main(["export", str(plant), "-o", str(xml)]) == 0
    assert main(["import", str(xml), "-o", str(tmp_path / "back"), "--strict"]) == 0
    capsys.readouterr()
    before, after = load_plant(str(plant)), load_plant(str(tmp_path / "back" / "plant.yaml"))
    assert _said(after) == _said(before)
    for name in ("Feeder", "Packer"):
        assert main(["diff", str(plant.parent / f"{name.lower()}.yaml"),
                     str(tmp_path / "back" / f"{name}.yaml")]) == 0
    capsys.readouterr()


def test_a_plant_of_another_driver_keeps_its_driver(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The plant's drivers come back too (softplc's data), so that its points still name
    a driver of the plant."""
    plant = _plant(tmp_path / "p")
    plant.write_text(PLANT.replace("sim.", "io.").replace(
        "sim: {type: sim}", "io: {type: sim, on_fault: stop}"), encoding="utf-8")
    xml = tmp_path / "plant.xml"
    assert main(["export", str(plant), "-o", str(xml)]) == 0
    assert main(["import", str(xml), "-o", str(tmp_path / "back"), "--strict"]) == 0
    capsys.readouterr()
    before, after = load_plant(str(plant)), load_plant(str(tmp_path / "back" / "plant.yaml"))
    assert _said(after) == _said(before)
    assert {n: (d.type, d.config) for n, d in after.drivers.items()} == {
        n: (d.type, d.config) for n, d in before.drivers.items()}


def test_a_point_in_the_data_of_a_file_is_a_quoted_text(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A driver point in softplc's data of a file is written as one YAML string: it cannot
    add keys to the binding (nothing a file says becomes another part of the plant)."""
    plant = _plant(tmp_path / "p")
    xml = tmp_path / "plant.xml"
    assert main(["export", str(plant), "-o", str(xml)]) == 0
    text = xml.read_text(encoding="utf-8").replace(
        'source="sim.I1"', 'source="sim.I1, invert: false, x: {"')
    xml.write_text(text, encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "back")]) == 0
    capsys.readouterr()
    written = (tmp_path / "back" / "plant.yaml").read_text(encoding="utf-8")
    assert "Stop: {from: 'sim.I1, invert: false, x: {', invert: true}" in written


def test_a_chart_flag_bound_in_the_plant_is_refused_at_its_binding(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A chart flag (SFCPause) is no input of the chart's function block: the export says
    so at the binding rather than leave it out."""
    plant = _plant(tmp_path / "p")
    plant.write_text(PLANT.replace("      Stop: {from: sim.I1, invert: true}\n",
                                   "      Stop: {from: sim.I1, invert: true}\n"
                                   "      SFCPause: sim.I5\n"), encoding="utf-8")
    assert main(["export", str(plant), "-o", str(tmp_path / "x.xml")]) == 2
    err = capsys.readouterr().err
    assert "plant.yaml:20:17:" in err and "SFCPause" in err and "chart flag" in err
    assert not (tmp_path / "x.xml").exists()


def _plants() -> list[Path]:
    out = []
    for p in sorted([*(ROOT / "configs").rglob("*.yaml"), *(ROOT / "tests").rglob("*.yaml")]):
        try:
            if file_kind(str(p)) == "plant":
                load_plant(str(p))
                out.append(p)
        except SourceError:  # a plant written to be refused
            continue
    return out


@pytest.mark.parametrize("plant", _plants(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_plant_of_the_project_round_trips(plant: Path, tmp_path: Path, tc6: Any,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Every plant of configs/ and of the tests: the export is valid, and its import has
    the same instances, charts and bindings."""
    xml = tmp_path / "p.xml"
    xml.write_text(export_plant(load_plant(str(plant))), encoding="utf-8")
    tc6.validate(str(xml))
    assert main(["import", str(xml), "-o", str(tmp_path / "o"), "--strict"]) == 0
    capsys.readouterr()
    assert _said(load_plant(str(tmp_path / "o" / "plant.yaml"))) == _said(
        load_plant(str(plant)))
