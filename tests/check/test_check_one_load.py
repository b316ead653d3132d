"""``softplc check`` reads a chart once (its kind is told from the document it loads), and
loads each other file once for its checks (besides telling its kind): the
loaders' diagnostics carry the codes and positions, so nothing is patched and reloaded."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

import pytest

import runtime.checker.check as check
import runtime.language.filekind as filekind
import runtime.language.grafcetfile as grafcetfile
import runtime.language.plantfile as plantfile
from runtime.checker.check import CheckRun, check_files, exit_status

CHART = """\
grafcet: Small
inputs: [iA, iB]
outputs: [oX, oY]
memory: {sN: 0}
steps:
  gsA: {actions: ["P1 oX", "on ↑iA do oY", "N oX if ↑iB", "N sN := sN + 1"]}
  gsB: {actions: [oX, oY]}
transitions:
  - {from: gsA, to: gsB, when: iA}
  - {from: gsB, to: gsA, when: "iA'·iB"}
"""

PLANT = """\
drivers: {sim: {type: sim}}
instances:
  a:
    grafcet: small.yaml
    inputs: {iA: sim.I0}
    outputs: {oX: sim.Q0, oY: sim.Q1}
  b:
    grafcet: small.yaml
    inputs: {iA: sim.I1, iB: sim.I2}
    outputs: {oX: sim.Q2, oY: sim.Q1}
"""


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> Counter[str]:
    """How many times each file is read as YAML."""
    count: Counter[str] = Counter()
    for module in (check, filekind, grafcetfile, plantfile):
        real = module.load_yaml

        def counting(path: str, *args: Any, real: Any = real) -> Any:
            count[path.rsplit("/", 1)[-1]] += 1
            return real(path, *args)

        monkeypatch.setattr(module, "load_yaml", counting)
    return count


def test_a_chart_with_several_rule_errors_is_read_once(
        write: Callable[[str, str], str], reads: Counter[str]) -> None:
    res = check_files([write("small.yaml", CHART)])
    codes = [d.code for r in res for d in r.diags]
    assert codes.count("G105") == 2 and codes.count("G106") == 1 and "G101" in codes
    assert "G205" in codes  # the rest of the chart was checked
    assert reads == {"small.yaml": 1}  # its kind told from the document that is loaded


def test_a_plant_with_binding_errors_is_read_once(
        write: Callable[[str, str], str], reads: Counter[str]) -> None:
    write("small.yaml", CHART.replace('"P1 oX", "on ↑iA do oY", "N oX if ↑iB", ', "").replace(
        "gsA: {", "gsA: {initial: true, "))
    res = check_files([write("plant.yaml", PLANT)])
    assert [(d.code, d.line) for d in res[0].diags] == [("G301", 5), ("G302", 10)]
    assert exit_status(res) == 2
    # the plant: once (its kind is told from the document its load uses); its chart: once
    # for the plant, once to check it (the plant's load did not give it)
    assert reads == {"plant.yaml": 1, "small.yaml": 2}


GOOD_PLANT = """\
drivers: {sim: {type: sim}}
instances:
  a:
    grafcet: small.yaml
    inputs: {iA: sim.I0, iB: sim.I1}
    outputs: {oX: sim.Q0, oY: sim.Q1}
  b:
    grafcet: small.yaml
    inputs: {iA: sim.I2, iB: sim.I3}
    outputs: {oX: sim.Q2, oY: sim.Q3}
"""


@pytest.mark.parametrize("command", ["compile", "draw"])
def test_compile_and_draw_read_each_file_once(
        write: Callable[[str, str], str], reads: Counter[str], tmp_path: Any,
        command: str) -> None:
    from runtime import cli
    from runtime.drawing import chart

    chart_text = CHART.replace('"P1 oX", "on ↑iA do oY", "N oX if ↑iB", ', "").replace(
        "gsA: {", "gsA: {initial: true, ")
    write("small.yaml", chart_text)
    plant = write("plant.yaml", GOOD_PLANT)
    if command == "compile":
        assert cli.main(["compile", plant]) == 0
    else:
        chart.load_chart(plant, None)
    assert reads == {"plant.yaml": 1, "small.yaml": 1}
    reads.clear()
    if command == "compile":
        assert cli.main(["compile", str(tmp_path / "small.yaml")]) == 0
    else:
        chart.load_chart(str(tmp_path / "small.yaml"), None)
    assert reads == {"small.yaml": 1}


def test_check_run_is_the_checker_session() -> None:
    run = CheckRun(paths=["x.yaml"])
    assert run.paths == ["x.yaml"] and not run.charts_done
