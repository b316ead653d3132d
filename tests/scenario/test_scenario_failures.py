"""Scenarios that must fail do, each with the one line docs/testing-charts.md documents:
FILE:LINE:COL of the expectation, the scan, what was expected, what the trace holds, and the
nearest scan where it would have held. The drawer tester's run (kit.STORY) is known scan
by scan: tester1 opens from 500 ms, closes from 800 ms, opens again from 1100 ms to 2 s."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.scenario.kit import run


def one_failure(tmp_path: Path, entry: str) -> str:
    """The failure line of a scenario of the one expectation ``entry`` (at its place)."""
    out, path, lines = run(tmp_path, [entry])
    assert out.error is None, out.error
    assert [c.failure is not None for c in out.cases] == [True], out.cases
    line = out.cases[0].failure
    assert line is not None
    prefix = f"{path}:{lines[0]}:"
    assert line.startswith(prefix), line
    return line[len(prefix):]


def col(entry: str, name: str) -> int:
    """The column of ``name`` in a scenario line ``  - ENTRY``."""
    return 5 + entry.index(name)


@pytest.mark.parametrize(("entry", "key", "message"), [
    # a wrong value in the right scan
    ("{at: 500ms, expect: {tester1.oAbrir: 0}}", "tester1.oAbrir",
     "cycle 50 (t = 500ms): expected tester1.oAbrir = 0; the trace holds tester1.oAbrir = 1; "
     "it holds at cycle 49 (t = 490ms), 1 scan earlier"),
    # the right value one scan too early: a change at t is seen by the scan at t
    ("{at: 490ms, expect: {tester1.gsAbrir.X: 1}}", "tester1.gsAbrir.X",
     "cycle 49 (t = 490ms): expected tester1.gsAbrir.X = 1; the trace holds "
     "tester1.gsAbrir.X = 0; it holds at cycle 50 (t = 500ms), 1 scan later"),
    # never reached in the run
    ("{at: 1s, expect: {tester1.gsAveria.X: 1}}", "tester1.gsAveria.X",
     "cycle 100 (t = 1s): expected tester1.gsAveria.X = 1; the trace holds "
     "tester1.gsAveria.X = 0; it holds in no scan of the run"),
    # several names: every one shown; the place is the first that does not hold
    ("{at: 800ms, expect: {tester1.gsCerrar.X: 1, tester1.sCierres: 2}}", "tester1.sCierres",
     "cycle 80 (t = 800ms): expected tester1.gsCerrar.X = 1, tester1.sCierres = 2; the trace "
     "holds tester1.gsCerrar.X = 1, tester1.sCierres = 1; it holds in no scan of the run"),
    # a step's time (kept after the step is left)
    ("{at: 800ms, expect: {tester1.gsAbrir.T: 200ms}}", "tester1.gsAbrir.T",
     "cycle 80 (t = 800ms): expected tester1.gsAbrir.T = 200ms; the trace holds "
     "tester1.gsAbrir.T = 300ms; it holds at cycle 70 (t = 700ms), 10 scans earlier"),
    ("{cycle: 100, expect: {tester1.SFCCurrentStep: gsAbrir}}", "tester1.SFCCurrentStep",
     "cycle 100 (t = 1s): expected tester1.SFCCurrentStep = gsAbrir; the trace holds "
     "tester1.SFCCurrentStep = gsCerrar; it holds at cycle 110 (t = 1s100ms), 10 scans later"),
    ("{at: 700ms, within: 50ms, expect: {tester1.gsCerrar.X: 1}}", "tester1.gsCerrar.X",
     "cycle 70 (t = 700ms) to cycle 75 (t = 750ms): expected tester1.gsCerrar.X = 1 in some "
     "scan; the trace holds tester1.gsCerrar.X = 0 throughout; it holds at cycle 80 "
     "(t = 800ms), 5 scans later"),
    ("{from: 0s, to: 1s, never: {tester1.oAbrir: 1}}", "tester1.oAbrir",
     "cycle 50 (t = 500ms): expected never tester1.oAbrir = 1 from 0s to 1s; the trace holds "
     "tester1.oAbrir = 1 (30 scans of 100 break it, the last cycle 79)"),
    ("{always: {tester1.oParado: 1}}", "tester1.oParado",
     "cycle 50 (t = 500ms): expected always tester1.oParado = 1 from 0s to 2s; the trace "
     "holds tester1.oParado = 0 (150 scans of 200 break it, the last cycle 199)"),
    ("{on_rise: tester1.iAbierto, expect: {tester1.gsAbrir.X: 1}}", "tester1.gsAbrir.X",
     "cycle 80 (t = 800ms), where tester1.iAbierto rises: expected tester1.gsAbrir.X = 1; "
     "the trace holds tester1.gsAbrir.X = 0; it holds at cycle 79 (t = 790ms), 1 scan "
     "earlier"),
    # waiting for an edge that never comes: never reached
    ("{on_rise: tester1.gsAveria.X, expect: {tester1.oAbrir: 0}}", "tester1.gsAveria.X",
     "never reached: expected tester1.gsAveria.X to rise from 0s to 2s; it never does (it is "
     "0); nothing was checked"),
    ("{rises: {tester1.oAbrir: 1}}", "tester1.oAbrir",
     "from 0s to 2s: expected 1 rising edge of tester1.oAbrir; the trace holds 2 (at cycles "
     "50, 110); it holds for a window ending at cycle 109 (t = 1s90ms)"),
    ("{from: 0s, to: 1s, rises: {tester1.oCerrar: '>= 2'}}", "tester1.oCerrar",
     "from 0s to 1s: expected >= 2 rising edges of tester1.oCerrar; the trace holds 1 (at "
     "cycle 80); no end of the window makes it hold"),
    ("{name: the drawer closes, on_fall: tester1.iAbierto, expect: {tester1.oCerrar: 0}}",
     "tester1.oCerrar",
     "the drawer closes: cycle 90 (t = 900ms), where tester1.iAbierto falls: expected "
     "tester1.oCerrar = 0; the trace holds tester1.oCerrar = 1; it holds at cycle 79 "
     "(t = 790ms), 11 scans earlier"),
])
def test_a_failing_expectation_is_one_line(tmp_path: Path, entry: str, key: str,
                                           message: str) -> None:
    assert one_failure(tmp_path, entry) == f"{col(entry, key)}: error: {message}"


def test_expectations_that_hold_pass(tmp_path: Path) -> None:
    entries = ["{at: 500ms, expect: {tester1.oAbrir: 1, tester1.gsAbrir.X: 1}}",
               "{cycle: 80, expect: {tester1.SFCCurrentStep: gsCerrar, sim.Q1: 1}}",
               "{at: 450ms, within: 50ms, expect: {tester1.gsAbrir.X: 1}}",
               "{to: 500ms, never: {tester1.oAbrir: 1}}",
               "{from: 500ms, to: 800ms, always: {tester1.oAbrir: 1, tester1.oTest: 1}}",
               "{on_rise: tester1.iAbierto, expect: {tester1.gsCerrar.X: 1}}",
               "{on_fall: tester1.iMarcha, expect: {tester1.gsAbrir.X: 1}}",
               "{rises: {tester1.oAbrir: 2, tester1.oCerrar: 1, tester2.oAbrir: 0}}",
               "{at: 790ms, expect: {tester1.gsAbrir.T: '>= 290ms', tester1.sCierres: '< 1'}}",
               "{at: 800ms, expect: {tester1.tAveriaAbrir: false, tester2.gsParado.X: true}}"]
    out, _, _ = run(tmp_path, entries)
    assert out.error is None
    assert [(c.name, c.failure) for c in out.cases if c.failure] == []
    assert len(out.cases) == len(entries)
    assert out.scans == 200


def test_each_expectation_is_a_case_named_by_its_line(tmp_path: Path) -> None:
    out, _, lines = run(tmp_path, ["{at: 500ms, expect: {tester1.oAbrir: 1}}",
                                   "{name: interlock, never: {tester1.oAbrir: 1, "
                                   "tester1.oCerrar: 1}}"])
    assert [c.name for c in out.cases] == [f"line {lines[0]}: at 500ms",
                                           f"line {lines[1]}: interlock"]


FAULTY = """grafcet: Faulty
inputs: [iGo, iDiv: int]
outputs: [oRun]
steps:
  s0: {initial: true}
  s1: {actions: [oRun]}
transitions:
  - {from: s0, to: s1, when: iGo}
post:
  - tQ := 100 / iDiv
"""


def test_a_scan_fault_fails_the_run_and_what_comes_after(tmp_path: Path) -> None:
    (tmp_path / "faulty.yaml").write_text(FAULTY, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(
        "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\ninstances:\n"
        "  f:\n    grafcet: faulty.yaml\n    inputs: {iGo: {from: sim.I0}, iDiv: {from: "
        "sim.IW0}}\n    outputs: {oRun: {from: sim.Q0}}\n", encoding="utf-8")
    head = ("plant: plant.yaml\nduration: 1s\nset:\n  - {at: 0ms, f.iDiv: 1}\n"
            "  - {at: 200ms, f.iGo: 1}\n  - {at: 300ms, f.iDiv: 0}\nexpect:\n")
    out, path, lines = run(tmp_path, ["{at: 200ms, expect: {f.s1.X: 1, f.oRun: 1}}",
                                      "{at: 500ms, expect: {f.s1.X: 1}}"], head)
    assert out.scans == 30  # cycles 0-29; cycle 30 raised
    fault, before, after = (c.failure for c in out.cases)
    assert fault is not None and fault.startswith(f"{tmp_path / 'plant.yaml'}:4:3: error: "
                                                  "expected every scan to end normally")
    assert "in cycle 30 (t = 300 ms): ZeroDivisionError" in fault
    assert before is None
    assert after == (f"{path}:{lines[1]}:5: error: at 500ms: not checked: the run stopped at "
                     f"cycle 29 (t = 290ms) ({fault})")
