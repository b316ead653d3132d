"""``softplc import`` is safe to repeat on an edited plant: the plant file the user edited is
never overwritten (not even with --force), ``--chart-only`` updates the charts alone, and a
POU named like the plant file does not collide with it."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.cli import main

#: a Beremiz-style project with one SFC POU named ``NAME``
PROJECT = """\
<?xml version="1.0" encoding="utf-8"?>
<project xmlns="http://www.plcopen.org/xml/tc6_0201">
  <fileHeader companyName="t" productName="t" productVersion="1"
              creationDateTime="2024-01-01T00:00:00"/>
  <contentHeader name="p"><coordinateInfo><fbd><scaling x="0" y="0"/></fbd>
    <ld><scaling x="0" y="0"/></ld><sfc><scaling x="0" y="0"/></sfc></coordinateInfo>
  </contentHeader>
  <types><dataTypes/><pous>
    <pou name="NAME" pouType="program">
      <interface>
        <inputVars><variable name="Go"><type><BOOL/></type></variable></inputVars>
        <outputVars><variable name="Lamp"><type><BOOL/></type></variable></outputVars>
      </interface>
      <body><SFC>
        <step localId="1" name="Idle" initialStep="true">
          <connectionPointIn><connection refLocalId="4"/></connectionPointIn>
        </step>
        <transition localId="2">
          <connectionPointIn><connection refLocalId="1"/></connectionPointIn>
          <condition><inline name=""><ST><xhtml:p xmlns:xhtml="http://www.w3.org/1999/xhtml"
            >COND</xhtml:p></ST></inline></condition>
        </transition>
        <step localId="3" name="Run">
          <connectionPointIn><connection refLocalId="2"/></connectionPointIn>
        </step>
        <actionBlock localId="5">
          <connectionPointIn><connection refLocalId="3"/></connectionPointIn>
          <action localId="6"><reference name="Lamp"/></action>
        </actionBlock>
        <transition localId="4">
          <connectionPointIn><connection refLocalId="3"/></connectionPointIn>
          <condition><inline name=""><ST><xhtml:p xmlns:xhtml="http://www.w3.org/1999/xhtml"
            >NOT Go</xhtml:p></ST></inline></condition>
        </transition>
      </SFC></body>
    </pou>
  </pous></types>
  <instances><configurations/></instances>
</project>
"""


def project(tmp_path: Path, name: str, cond: str = "Go") -> Path:
    xml = tmp_path / f"{name}-{len(cond)}.xml"
    xml.write_text(PROJECT.replace("NAME", name).replace("COND", cond), encoding="utf-8")
    return xml


def test_a_pou_named_like_the_plant_file_does_not_collide(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Was: 'plant.yaml exist(s)' (the chart and the skeleton share the name), and with
    --force the chart was replaced by the skeleton."""
    out = tmp_path / "out"
    assert main(["import", str(project(tmp_path, "plant")), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"POU plant -> {out / 'plant_chart.yaml'}" in err
    assert sorted(p.name for p in out.iterdir()) == ["plant.yaml", "plant_chart.yaml"]
    assert (out / "plant_chart.yaml").read_text(encoding="utf-8").count("grafcet: plant") == 1
    assert "grafcet: plant_chart.yaml" in (out / "plant.yaml").read_text(encoding="utf-8")
    assert main(["simulate", str(out / "plant.yaml"), "--cycles", "3"]) == 0
    assert "final steps: plant: Idle" in capsys.readouterr().err


def test_an_edited_plant_is_never_overwritten(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    first = project(tmp_path, "Machine")
    assert main(["import", str(first), "-o", str(out)]) == 0
    plant = out / "plant.yaml"
    # not edited: --force replaces it (and the chart) with what the file says now
    assert main(["import", str(first), "-o", str(out), "--force"]) == 0
    capsys.readouterr()
    edited = plant.read_text(encoding="utf-8").replace("sim.I0", "sim.I7")
    plant.write_text(edited, encoding="utf-8")
    second = project(tmp_path, "Machine", "Go AND NOT Lamp")
    assert main(["import", str(second), "-o", str(out), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == (
        f"softplc import: error: {plant} was edited since softplc import wrote it: not "
        "overwritten, even with --force (--chart-only updates the charts alone; remove it "
        "for a new skeleton)")
    assert plant.read_text(encoding="utf-8") == edited
    assert "when: Go}" in (out / "Machine.yaml").read_text(encoding="utf-8")  # untouched
    # --chart-only: the charts alone, the edited plant as it is, and it runs them
    assert main(["import", str(second), "-o", str(out), "--chart-only"]) == 0
    assert "not written (--chart-only)" in capsys.readouterr().err
    assert plant.read_text(encoding="utf-8") == edited
    assert "when: Go AND NOT Lamp" in (out / "Machine.yaml").read_text(encoding="utf-8")
    assert main(["simulate", str(plant), "--cycles", "3"]) == 0


def test_chart_only_writes_no_plant(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["import", str(project(tmp_path, "Machine")), "-o", str(out),
                 "--chart-only"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["Machine.yaml"]
    capsys.readouterr()
