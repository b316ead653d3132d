"""The coverage shades the chart: ``softplc draw --coverage`` and the page of ``softplc web
--coverage`` (a real controller and web view) draw the steps and actions the scenarios
reached in green, those never reached in red, and the transitions never fired red."""

from __future__ import annotations

import re
import urllib.request
from pathlib import Path

import pytest

from runtime.drawing.chart import COVERED_FILL, MISSED_FILL, MISSED_STROKE
from tests.opcua.feedkit import wait_until
from tests.scenario.kit import DRAWER, ROOT, cli, write
from tests.web.kit import start, stop, write_plant

DOOR = ROOT / "configs" / "security_door"


def step_fill(svg: str, step: str) -> str:
    m = re.search(rf'<g class="step-group" data-step="{step}">\s*(?:<title>[^<]*</title>\s*)?'
                  r'<rect [^>]*fill="([^"]+)"', svg)
    assert m, step
    return m.group(1)


def missed_transitions(svg: str) -> list[str]:
    """The transitions drawn as never fired (their group's index)."""
    out = []
    for m in re.finditer(r'<g class="transition-group" data-transition="(\d+)">(.*?)</g>',
                         svg, re.S):
        if f'stroke="{MISSED_STROKE}"' in m.group(2):
            out.append(m.group(1))
    return out


def test_draw_shades_the_chart_by_the_coverage_of_its_scenarios(tmp_path: Path) -> None:
    cov = tmp_path / "cov.json"
    status, out = cli("test", str(DOOR / "security_door.test.yaml"), "--coverage-file", str(cov))
    assert status == 0, out
    svg_path = tmp_path / "door.svg"
    assert cli("draw", str(DOOR / "security_door.yaml"), "--coverage", str(cov), "-o",
               str(svg_path), "--layout", "python")[0] == 0
    svg = svg_path.read_text(encoding="utf-8")
    assert "coverage 91.8% over 1 scenario(s): green reached, red never" in svg
    assert step_fill(svg, "gsAlarma") == COVERED_FILL
    assert step_fill(svg, "gsInicio") == COVERED_FILL
    # the story never raises the alarm by time from gsSubiendo1, gsCruzando1, gsSubiendo2
    assert sorted(missed_transitions(svg)) == ["3", "5", "9"]
    # nor powers up with door 2 open: gsInicio's second action never runs
    assert svg.count(f'fill="{MISSED_FILL}"') == 2  # its qualifier and its body
    # with the alarms' scenario too, everything is reached
    status, _ = cli("test", str(DOOR), "--coverage-file", str(cov))
    assert status == 0
    assert cli("draw", str(DOOR / "security_door.yaml"), "--coverage", str(cov), "-o",
               str(svg_path), "--layout", "python")[0] == 0
    svg = svg_path.read_text(encoding="utf-8")
    assert missed_transitions(svg) == [] and MISSED_FILL not in svg
    assert "coverage 100.0% over 2 scenario(s)" in svg


def test_draw_says_when_the_file_has_no_coverage_of_the_chart(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cov = tmp_path / "cov.json"
    cli("test", str(DRAWER), "--coverage-file", str(cov))
    capsys.readouterr()
    status, _ = cli("draw", str(DOOR / "security_door.yaml"), "--coverage", str(cov), "-o",
                    str(tmp_path / "x.svg"))
    assert status == 2
    assert capsys.readouterr().err == (
        f"{cov}:1:1: error: no coverage of grafcet SecurityDoor "
        f"({DOOR / 'security_door.yaml'}) in this file\n")
    assert not (tmp_path / "x.svg").exists()


def test_the_page_shades_the_chart_by_coverage(tmp_path: Path) -> None:
    """``softplc web --coverage``: the chart the page shows is shaded."""
    run = tmp_path / "run"
    run.mkdir()
    plant = write_plant(run, users=False)
    # a scenario of this plant that never raises a failure
    path, _ = write(tmp_path, ["{at: 500ms, expect: {tester1.gsAbrir.X: 1}}"],
                    head=(DRAWER / "drawer_tester.test.yaml").read_text(encoding="utf-8")
                    .split("expect:")[0].replace("plant: plant_sim.yaml", f"plant: {plant}")
                    .replace("script: story.yaml", "") + "duration: 2s\nset:\n"
                    "  - {at: 0ms, sim.I0: 1, tester1.iCerrado: 1}\n"
                    "  - {at: 500ms, tester1.iMarcha: 1}\nexpect:\n")
    cov = tmp_path / "cov.json"
    status, out = cli("test", str(path), "--coverage-file", str(cov))
    assert status == 0, out
    ctl = start(run, "run", str(plant), "--sim")
    web = None
    try:
        # ${RUNTIME_DIR} is the plant's own directory under $XDG_RUNTIME_DIR/softplc
        wait_until(lambda: any(run.glob("softplc/*/feed.sock")) or ctl.popen.poll() is not None,
                   30.0, "the feed")
        web = start(run, "web", str(plant), "--coverage", str(cov))
        found: list[str] = []

        def listening() -> bool:
            found[:] = [m.group(1) for ln in web.lines
                        if (m := re.search(r"is at (https?://\S+/)", ln))]
            return bool(found) or web.popen.poll() is not None
        wait_until(listening, 30.0, "the web view's address")
        assert found, web.log()
        with urllib.request.urlopen(found[0] + "chart/tester1.svg", timeout=30) as resp:
            svg = resp.read().decode("utf-8")
    finally:
        stop(web, ctl)
    assert "tester1: DrawerTester (coverage " in svg
    assert step_fill(svg, "gsAbrir") == COVERED_FILL
    assert step_fill(svg, "gsAveria") == MISSED_FILL
    assert step_fill(svg, "gsCerrar") == MISSED_FILL


def test_the_page_refuses_a_coverage_file_that_is_not_one(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plant = write_plant(tmp_path, users=False)
    bad = tmp_path / "cov.json"
    bad.write_text("[]", encoding="utf-8")
    status, _ = cli("web", str(plant), "--coverage", str(bad))
    assert status == 2
    assert capsys.readouterr().err == (
        f"{bad}:1:1: error: not a coverage file: expected the JSON that softplc test "
        "--coverage-file writes (format 'softplc-coverage', version 1)\n")
