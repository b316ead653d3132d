"""Every construct of docs/plcopen.md's Importing table that has a test file here round-trips:
import, export of each chart (valid against the schema), import again: ``softplc diff``
says no change, and the plant of the first import runs the charts of the second scan by
scan as it runs its own (the hand-worked scans of each file are in test_plcopen_behaviour,
test_plcopen_editor, test_plcopen_blocks and test_plcopen_types). What changes in the
file (not in the chart) is tested at the end: a condition drawn in FBD is exported as ST."""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.engine.simulate import Simulation
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import load_plant
from runtime.plcopen.export import export_chart
from runtime.plcopen.importer import import_file
from tests.plcopen import test_plcopen_blocks as blocks
from tests.plcopen import test_plcopen_import as imp
from tests.plcopen.plcopenkit import DATA, shape


def _pou(condition: str, network: str = "", transitions: str = "", negated: bool = False
         ) -> Callable[[], str]:
    return lambda: imp.POU.format(condition=condition, network=network,
                                  transitions=transitions,
                                  negated=' negated="true"' if negated else "")


def _data(name: str) -> Callable[[], str]:
    return lambda: (DATA / name).read_text(encoding="utf-8")


FBD = '<connectionPointIn><connection refLocalId="13"/></connectionPointIn>'
LD = '<connectionPointIn><connection refLocalId="25"/></connectionPointIn>'
#: construct -> the PLCopen file holding it
CONSTRUCTS: dict[str, Callable[[], str]] = {
    "externals and globals": _data("beremiz_globals.xml"),
    "FBD condition: AND, OR, NOT, an edge": _pou(FBD, imp.FBD_OR),
    "LD condition: contacts in series and in parallel": _pou(LD, imp.LD_PARALLEL),
    "POU transition in ST, negated": _pou('<reference name="go"/>', "", imp.ST_TRANSITION,
                                          True),
    "TON in an FBD condition": lambda: blocks.project("TON", "condition"),
    "SR in an FBD condition": lambda: blocks.project("SR", "condition"),
    "TON in a POU transition's FBD body": lambda: blocks.project("TON", "transition"),
    "CTU in an LD action body": lambda: blocks.project("CTU", "action"),
    "LD action, comments, FBD conditions with blocks": _data("beremiz_cell.xml"),
    "jump steps, macro-step, qualifiers S R D P N L SD DS SL P0": _data("beremiz_mixer.xml"),
    "program POU instantiating SFC function blocks": _data("beremiz_line.xml"),
    "CODESYS vendor data, entry/main/exit actions": _data("codesys_press.xml"),
    "typed and located variables": _data("typed_located.xml"),
}


def _script(plant: Path) -> str:
    """Every input bound to a simulated point, changed at staggered times: bools on, off and
    on again, numbers through three values (1.5 s)."""
    p = load_plant(str(plant))
    lines = ["duration: 1500ms", "set:"]
    k = 0
    for inst in p.instances.values():
        for sig, b in inst.inputs.items():
            var = inst.grafcet.variables.get(sig)
            if b.driver != "sim" or var is None or var.type.value not in ("bool", "int",
                                                                          "real"):
                continue
            values = [1, 0, 1] if var.type.value == "bool" else [15, 3, 40]
            for n, v in enumerate(values):
                lines.append(f"  - {{at: {40 + 30 * k + 400 * n}ms, {inst.name}.{sig}: {v}}}")
            k += 1
    if k == 0:
        lines[1:] = []
    return "\n".join(lines) + "\n"


def _trace(plant: Path, script: Path) -> list[dict[str, Any]]:
    return list(Simulation(str(plant), str(script)).run(trace=True))


@pytest.mark.parametrize("construct", list(CONSTRUCTS))
def test_the_construct_round_trips(construct: str, tmp_path: Path, tc6: Any,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "src.xml"
    src.write_text(CONSTRUCTS[construct](), encoding="utf-8")
    first, again = tmp_path / "first", tmp_path / "again"
    assert main(["import", str(src), "-o", str(first)]) == 0
    pous = [c.pou for c in import_file(str(src)).charts]
    assert pous
    again.mkdir()
    for k, pou in enumerate(pous):
        chart = first / f"{pou}.yaml"
        xml = tmp_path / f"{k}.xml"
        xml.write_text(export_chart(load_grafcet(str(chart))), encoding="utf-8")
        tc6.validate(str(xml))
        back = tmp_path / f"back{k}"
        assert main(["import", str(xml), "-o", str(back), "--strict"]) == 0
        assert shape(load_grafcet(str(back / f"{pou}.yaml"))) == shape(
            load_grafcet(str(chart)))
        capsys.readouterr()
        assert main(["diff", str(chart), str(back / f"{pou}.yaml")]) == 0
        assert capsys.readouterr().out.startswith("no change\n")
        shutil.copy(back / f"{pou}.yaml", again / f"{pou}.yaml")
    # the first plant, running the charts imported again: the same scans
    shutil.copy(first / "plant.yaml", again / "plant.yaml")
    script = tmp_path / "script.yaml"
    script.write_text(_script(first / "plant.yaml"), encoding="utf-8")
    expected = _trace(first / "plant.yaml", script)
    assert len(expected) > 10
    assert _trace(again / "plant.yaml", script) == expected


def test_an_fbd_condition_is_exported_as_st_and_its_blocks_as_post(tmp_path: Path) -> None:
    """What a round trip changes, in the file: a condition drawn in FBD with a TON is
    written as an inline ST condition reading the block's output (``X.Q``), its block call
    as a statement of softplc's ``post`` data (no FBD network is left in the SFC body); the
    chart read back is the same chart (above), scan by scan."""
    src = tmp_path / "src.xml"
    src.write_text(blocks.project("TON", "condition"), encoding="utf-8")
    assert "<block " in src.read_text(encoding="utf-8")
    g = import_file(str(src)).charts[0].grafcet
    xml = export_chart(g)
    sfc = xml.split("<SFC>")[1].split("</SFC>")[0]
    assert "<block " not in sfc and "<inVariable" not in sfc
    conditions = re.findall(r"<condition>\s*<inline[^>]*>\s*<ST>\s*<xhtml:p><!\[CDATA\[(.*?)\]\]>",
                            sfc)
    assert conditions == ["X.Q", "c"]
    assert re.findall(r"<sp:post>(.*?)</sp:post>", xml) == ["X(IN := a, PT := T#300ms)"]
