"""Issue 2, item 4, through the command line: every fault listed there, in a file given to
``softplc compile``, gives exit status 2 and exactly one line ``FILE:LINE:COL: error: ...``
on stderr, at the offending text, naming what was expected and what was found; never a
traceback. (test_lang_errors.py checks the same faults on the loader, in more forms.)"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.cli import main
from tests.language.langkit import where, write

ROOT = Path(__file__).resolve().parents[2]

CHART = """\
grafcet: T
inputs: [iParo, iMarcha]
outputs: [oA]
memory:
  sN: 0
timers: [timeT]
blocks:
  tonA: TON
steps:
  gsA: {initial: true, actions: [ACT]}
  gsB: {}
transitions:
  - {from: gsA, to: gsB, when: "COND"}
"""

PLANT = """\
drivers: {sim: {type: sim}}
instances:
  a:
    grafcet: chart.yaml
    inputs: {iParo: sim.I0, iMarcha: sim.I1}
    outputs: {oA: sim.Q0}
"""


def chart(act: str = "oA", cond: str = "iParo") -> str:
    return CHART.replace("ACT", act).replace("COND", cond)


#: fault -> (chart text, plant text or None, needle where the error points, words)
FAULTS: dict[str, tuple[str, str | None, str, list[str]]] = {
    "yaml syntax": ("grafcet: T\nsteps: {a: [}\n", None, "}", ["YAML syntax", "expected",
                                                              "found '}'"]),
    "unknown key": (chart().replace("timers:", "timerz:"), None, "timerz",
                    ["unknown key 'timerz'", "expected one of", "did you mean 'timers'"]),
    "unknown variable": (chart(cond="iMarca"), None, "iMarca",
                         ["unknown variable 'iMarca'", "did you mean 'iMarcha'"]),
    "unknown step": (chart(cond="gsC.X"), None, "gsC.X",
                     ["unknown step 'gsC'", "did you mean 'gsB'"]),
    "unknown timer": (chart(cond="timeX.End()"), None, "timeX",
                      ["unknown timer 'timeX'", "did you mean 'timeT'"]),
    "unknown block": (chart(cond="tonB.Q"), None, "tonB",
                      ["unknown function block 'tonB'", "did you mean 'tonA'"]),
    "unbalanced parentheses": (chart(cond="(iParo + iMarcha"), None, '"}',
                               ["unbalanced parentheses", "expected ')'", "found end of text"]),
    "bad time literal": (chart(cond="gsA.T > 1s10m"), None, "1s10m",
                         ["bad time literal '1s10m'", "expected"]),
    "unknown qualifier": (chart(act="X oA"), None, "X oA",
                          ["unknown qualifier 'X'", "expected one of N S R L D P P1 P0"]),
    "qualifier without its time": (chart(act="L oA"), None, "oA]}",
                                   ["expected a time after qualifier L", "found 'oA'"]),
    "P1 on a bare variable": (chart(act="P1 oA"), None, "oA]}",
                              ["expected statements after P1", "found the bare variable 'oA'"]),
    "P0 on a bare variable": (chart(act="P0 oA"), None, "oA]}",
                              ["expected statements after P0", "found the bare variable 'oA'"]),
    "event on a bare variable": (chart(act="on ↑iParo do oA"), None, "oA]}",
                                 ["expected statements after 'do'", "bare variable 'oA'"]),
    "type error": (chart(cond="iMarcha + 3 >= gsA.T"), None, "iMarcha + 3",
                   ["type error: expected a time to compare with time 'gsA.T'",
                    "found int 'iMarcha + 3'"]),
    "no initial step": (chart().replace("initial: true, ", ""), None, "steps:",
                        ["no initial step", "expected a step with 'initial: true'",
                         "found none"]),
    "transition to an unknown step": (chart().replace("to: gsB", "to: gsBB"), None, "gsBB",
                                      ["unknown step 'gsBB'", "did you mean 'gsB'"]),
    "input left unbound": (chart(), PLANT.replace(", iMarcha: sim.I1", ""), "inputs:",
                           ["leaves input 'iMarcha'", "unbound", "expected a binding",
                            "found none"]),
    "output left unbound": (chart(), PLANT.replace("{oA: sim.Q0}", "{}"), "outputs:",
                            ["leaves output 'oA'", "unbound"]),
    "physical output bound twice": (
        chart(), PLANT + PLANT.split("instances:\n")[1].replace("  a:", "  b:").replace(
            "sim.I", "sim.I1"), "sim.Q0", ["physical output 'sim.Q0' is bound twice",
                                           "'b.oA'", "'a.oA'"]),
    "instance link of the wrong type": (
        chart(), PLANT + PLANT.split("instances:\n")[1].replace("  a:", "  b:").replace(
            "sim.I1", "a.gsA.T").replace("sim.Q0", "sim.Q1"), "a.gsA.T",
        ["type error: expected a bool signal for 'b.iMarcha'", "found time 'a.gsA.T'"]),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_compile_reports_one_line_at_the_fault_and_exits_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], fault: str) -> None:
    text, plant, needle, words = FAULTS[fault]
    cpath = write(tmp_path, "chart.yaml", text)
    if plant is None:  # a fault in the chart
        target = path = cpath
        line, col = where(text, needle)
    else:  # a fault in the plant's bindings
        target = path = write(tmp_path, "plant.yaml", plant)
        line, col = where(plant, needle, 1 if fault == "physical output bound twice" else 0)
    rc = main(["compile", target])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    m = re.match(r"(.+):(\d+):(\d+): error: (.+)$", lines[0])
    assert m, lines[0]
    assert (m.group(1), int(m.group(2)), int(m.group(3))) == (path, line, col), lines[0]
    for w in words:
        assert w in m.group(4), (w, lines[0])


def test_the_console_script_exits_2_without_a_traceback(tmp_path: Path) -> None:
    """The real process: exit status 2 and one line, for a chart and for a plant."""
    cpath = write(tmp_path, "chart.yaml", chart(act="P1 oA"))
    ppath = write(tmp_path, "plant.yaml", PLANT)
    for target in (cpath, ppath):
        proc = subprocess.run([sys.executable, "-m", "runtime.cli", "compile", target],
                              capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert proc.returncode == 2
        assert "Traceback" not in proc.stderr and len(proc.stderr.splitlines()) == 1
        assert proc.stderr.startswith(f"{cpath}:10:")
