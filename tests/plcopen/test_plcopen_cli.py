"""``softplc import`` and ``softplc export`` as a user runs them: files written, never
overwritten without --force, --strict, the plant skeleton running at once under
``softplc simulate`` and ``softplc run --sim``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from runtime.cli import main
from tests.plcopen.plcopenkit import DATA, ROOT

SOFTPLC = str(Path(sys.executable).parent / "softplc")
DRAWER = str(ROOT / "configs/drawer_tester/drawer_tester.yaml")


def test_export_to_standard_output(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["export", DRAWER, "--layout", "python"]) == 0
    out = capsys.readouterr().out
    assert out.startswith('<?xml version="1.0" encoding="utf-8"?>\n<project ')
    assert '<pou name="DrawerTester" pouType="program">' in out


def test_export_never_overwrites_without_force(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    target = tmp_path / "d.xml"
    target.write_text("edited in an editor", encoding="utf-8")
    assert main(["export", DRAWER, "-o", str(target)]) == 2
    assert capsys.readouterr().err == (f"{target}:1:1: error: exists: not overwritten "
                                       "(remove it, or --force)\n")
    assert target.read_text(encoding="utf-8") == "edited in an editor"
    assert main(["export", DRAWER, "-o", str(target), "--force"]) == 0
    assert "DrawerTester exported (4 steps, 7 transitions)" in capsys.readouterr().err
    assert target.read_text(encoding="utf-8").startswith("<?xml")


def test_export_refuses_a_transition_across_levels(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    chart = tmp_path / "c.yaml"
    chart.write_text("""\
grafcet: Cross
inputs: [a]
steps:
  s0: {initial: true}
  m:
    macro:
      steps:
        e: {entry: true}
        x: {exit: true}
      transitions:
        - {from: e, to: x, when: a}
transitions:
  - {from: s0, to: m, when: a}
  - {from: s0, to: x, when: a}
""", encoding="utf-8")
    assert main(["export", str(chart)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"{chart}:14:5: error: cannot export transition 'a': it is "
                          "written in the chart but links step 'x' of another level")


def test_import_writes_the_charts_and_a_plant_and_overwrites_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(out)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len([ln for ln in err if ": warning: " in ln]) == 5
    assert err[-2:] == [f"{DATA / 'beremiz_mixer.xml'}: POU Mixer -> {out / 'Mixer.yaml'} "
                        "(8 steps, 8 transitions, 16 actions)",
                        f"{out / 'plant.yaml'}: plant skeleton on simulated I/O "
                        "(1 instance(s))"]
    assert sorted(p.name for p in out.iterdir()) == ["Mixer.yaml", "plant.yaml"]
    chart = (out / "Mixer.yaml").read_text(encoding="utf-8")
    (out / "Mixer.yaml").write_text(chart + "# my edit\n", encoding="utf-8")
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(out)]) == 2
    assert "exist(s): not overwritten" in capsys.readouterr().err
    assert (out / "Mixer.yaml").read_text(encoding="utf-8").endswith("# my edit\n")
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(out), "--force"]) == 0
    assert (out / "Mixer.yaml").read_text(encoding="utf-8") == chart


def test_strict_refuses_what_would_be_left_out(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(out), "--strict"]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        "softplc import: error: 5 element(s) would be left out or changed (--strict): "
        "nothing written")
    assert not out.exists()
    # a note that loses nothing (the scan model chosen for a CODESYS file) is no refusal
    assert main(["import", str(DATA / "codesys_press.xml"), "-o", str(out), "--strict"]) == 0
    assert ": note: POU 'Press' comes from CODESYS" in capsys.readouterr().err


def test_import_one_pou(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "--pou", "Pump",
                 "-o", str(tmp_path)]) == 2
    assert capsys.readouterr().err.endswith("error: no POU named 'Pump' in the file (POUs: "
                                            "Mixer)\n")


def test_the_plant_skeleton_simulates_and_runs_at_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["simulate", str(out / "plant.yaml"), "--cycles", "5"]) == 0
    assert "final steps: tank: Idle" in capsys.readouterr().err
    r = subprocess.run([SOFTPLC, "run", str(out / "plant.yaml"), "--sim", "--for", "300ms"],
                       capture_output=True, text=True, timeout=120, check=False)
    assert r.returncode == 0, r.stderr


def test_a_directory_that_cannot_be_written_is_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory", encoding="utf-8")
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(blocker)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == f"softplc import: error: {blocker}: File exists"
    assert main(["export", DRAWER, "-o", str(tmp_path / "no" / "such" / "d.xml")]) == 2
    assert capsys.readouterr().err == (f"softplc export: error: {tmp_path / 'no/such/d.xml'}"
                                       ": No such file or directory\n")


def test_a_failed_write_leaves_no_file_behind(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Every file of an import or none: a plant that cannot be written takes the chart
    written before it away again (here the plant's name is taken by a directory)."""
    out = tmp_path / "out"
    (out / "plant.yaml").mkdir(parents=True)
    assert main(["import", str(DATA / "beremiz_mixer.xml"), "-o", str(out), "--force"]) == 2
    assert "softplc import: error: " in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["plant.yaml"]
