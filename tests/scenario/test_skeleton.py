"""``softplc import --scenario``: beside the imported charts and their plant, a scenario
skeleton (plant.test.yaml) that names every input to set and every output to expect, runs
and passes as written, and is never overwritten."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.cli import main
from runtime.language.plantfile import load_plant
from runtime.language.yamlsrc import load_yaml
from tests.scenario.kit import ROOT, cli

DATA = ROOT / "tests" / "plcopen" / "data"


@pytest.mark.parametrize("xml", ["beremiz_mixer.xml", "codesys_press.xml"])
def test_the_skeleton_names_every_input_and_output_and_passes(
        tmp_path: Path, xml: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "imported"
    assert main(["import", str(DATA / xml), "-o", str(out), "--scenario"]) == 0
    skeleton = out / "plant.test.yaml"
    assert f"{skeleton}: scenario skeleton (softplc test {out})" in capsys.readouterr().err
    text = skeleton.read_text(encoding="utf-8")
    pdef = load_plant(str(out / "plant.yaml"))
    doc = load_yaml(str(skeleton))
    assert doc["plant"] == "plant.yaml"
    (first,) = doc["set"]
    for name, idef in pdef.instances.items():
        g = idef.grafcet
        assert {k for k in first if k != "at"} >= {f"{name}.{v.name}" for v in g.inputs}
        for v in g.outputs:  # to be expected: written out, commented
            assert f"  #     {name}.{v.name}: " in text
        initial = {f"{name}.{s.name}.X": 1 for s in g.leaf_steps() if s.initial}
        assert doc["expect"][0] == {"cycle": 0, "expect": initial}
    status, report = cli("test", str(out))
    assert status == 0, report
    assert report.startswith(f"{skeleton}: 1 passed")


def test_an_existing_scenario_is_kept(tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "imported"
    assert main(["import", str(DATA / "codesys_press.xml"), "-o", str(out)]) == 0
    assert not (out / "plant.test.yaml").exists()  # only when asked
    skeleton = out / "plant.test.yaml"
    skeleton.write_text("# my own story\n", encoding="utf-8")
    assert main(["import", str(DATA / "codesys_press.xml"), "-o", str(out), "--force",
                 "--scenario"]) == 0
    assert (f"{skeleton}: exists: kept (a scenario is never overwritten; remove it for a "
            "new skeleton)") in capsys.readouterr().err
    assert skeleton.read_text(encoding="utf-8") == "# my own story\n"
