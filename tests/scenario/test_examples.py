"""The example plants' scenarios (configs/*/*.test.yaml) pass, their coverage is what
docs/testing-charts.md says, and a deliberately broken copy of the drawer tester
(tests/scenario/broken_drawer: two transitions swapped) is caught by its own scenario."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.scenario.kit import DRAWER, ROOT, cli

DOCS = ROOT / "docs" / "testing-charts.md"
BROKEN = Path(__file__).resolve().parent / "broken_drawer"


def test_the_example_plants_scenarios_pass_with_the_coverage_the_docs_give(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)
    status, out = cli("test", "--coverage", "configs")
    assert status == 0, out
    lines = out.splitlines()
    runs = [re.sub(r" \(\d+ scans, [0-9.]+ s\)$", "", ln) for ln in lines
            if ln.startswith("configs/") and " passed" in ln]
    assert runs == ["configs/carriage/carriage.test.yaml: 11 passed",
                    "configs/compactadora/compactadora.test.yaml: 18 passed",
                    "configs/drawer_tester/drawer_tester.test.yaml: 50 passed",
                    "configs/reactor/reactor.test.yaml: 32 passed",
                    "configs/security_door/alarms.test.yaml: 15 passed",
                    "configs/security_door/security_door.test.yaml: 30 passed",
                    "configs/seed004_codesys/seed004.test.yaml: 9 passed",
                    "configs/seed004_codesys/seed004_simultaneous.test.yaml: 10 passed"]
    # the coverage report, line for line, as the docs show it
    start = lines.index("coverage (steps active, transitions fired, actions run, divergence "
                        "branches taken):")
    report = lines[start:-1]
    docs = DOCS.read_text(encoding="utf-8")
    block = "\n".join(report)
    assert block in docs, f"docs/testing-charts.md does not show this report:\n{block}"


def test_a_broken_chart_is_caught_by_its_scenario(tmp_path: Path) -> None:
    """The drawer tester's scenario, run on the broken copy: the stop at the end of the
    cycle is not obeyed (and what follows from it)."""
    text = (DRAWER / "drawer_tester.test.yaml").read_text(encoding="utf-8")
    text = text.replace("plant: plant_sim.yaml", f"plant: {BROKEN / 'plant_sim.yaml'}")
    text = text.replace("script: story.yaml", f"script: {DRAWER / 'story.yaml'}")
    scenario = tmp_path / "broken.test.yaml"
    scenario.write_text(text, encoding="utf-8")
    line = text.split("\n").index(
        "  - {at: 2900ms, expect: {tester1.gsParado.X: 1, tester1.sParo: 0, tester1.oParado: "
        "1, tester1.sCierres: 4}}") + 1
    status, out = cli("test", str(scenario))
    assert status == 1
    assert (f"{scenario}:{line}:27: error: cycle 290 (t = 2s900ms): expected "
            "tester1.gsParado.X = 1, tester1.sParo = 0, tester1.oParado = 1, tester1.sCierres "
            "= 4; the trace holds tester1.gsParado.X = 0, tester1.sParo = 1, tester1.oParado = "
            "0, tester1.sCierres = 4; it holds at cycle 1500 (t = 15s), 1210 scans later"
            ) in out.splitlines()
    assert "softplc test: 1 scenario: 47 passed, 3 failed, 0 in error" in out


def test_the_broken_copy_differs_from_the_chart_by_the_swap_only() -> None:
    good = (DRAWER / "drawer_tester.yaml").read_text(encoding="utf-8").splitlines()
    bad = (BROKEN / "drawer_tester.yaml").read_text(encoding="utf-8").splitlines()[4:]
    i = good.index("  - {from: gsCerrar, to: gsParado, when: tParo}      # before gsCerrar -> "
                   "gsAbrir: priority")
    assert bad[:i] == good[:i] and bad[i + 2:] == good[i + 2:]
    assert bad[i] == good[i + 1]
    assert (BROKEN / "plant_sim.yaml").read_text(encoding="utf-8") == (
        DRAWER / "plant_sim.yaml").read_text(encoding="utf-8")
