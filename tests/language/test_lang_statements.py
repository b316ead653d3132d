"""Statements as language.md defines them, compiled and run: IF, CASE, FOR, methods,
function-block calls, and the action forms."""

from __future__ import annotations

from tests.language.langkit import MS, load_error, run

HEAD = """\
grafcet: G
inputs: [iA, iB, {iN: int}]
outputs: [oX, oY]
memory: {sN: 0, sI: 0, sS: 0, sC: 0, sB: false, sE: 0, sV: 0s, sQ: false}
timers: [timeT]
blocks: {tonD: TON, ctr: CTU}
steps:
  gsA: {initial: true}
  gsB: {}
"""


def test_if_elsif_else() -> None:
    text = HEAD + """\
pre:
  - |
    IF iA THEN sN := 1
    ELSIF iB THEN sN := 2
    ELSE sN := 3
    END_IF
"""
    rows = run(text, [{"iA": 1, "iB": 1}, {"iA": 0, "iB": 1}, {"iA": 0, "iB": 0}], ["sN"])
    assert rows == [[1], [2], [3]]


def test_case_lists_ranges_and_else() -> None:
    text = HEAD + """\
pre:
  - |
    CASE iN OF
      1: sC := 10
      2, 3: sC := 20
      4..6: sC := 30
      -3..-2: sC := 40
    ELSE
      sC := 99
    END_CASE
"""
    values = [1, 2, 3, 4, 6, 7, -2, -3, -4, 0]
    rows = run(text, [{"iN": v} for v in values], ["sC"])
    assert [r[0] for r in rows] == [10, 20, 20, 30, 30, 99, 40, 40, 99, 99]


def test_for_bounds_step_and_final_value() -> None:
    text = HEAD + """\
pre:
  - sS := 0
  - FOR sI := 1 TO 10 BY 3 DO sS := sS + sI; END_FOR
  - sC := 0
  - FOR tK := iN TO 1 BY -1 DO sC := sC + tK; END_FOR
  - sE := tK
"""
    rows = run(text, [{"iN": 4}, {"iN": 0}], ["sS", "sI", "sC", "sE"])
    # 1+4+7+10; after the loop the variable holds the first value past the bound
    assert rows == [[22, 13, 10, 0], [22, 13, 0, 0]]


def test_for_bounds_are_evaluated_once() -> None:
    text = HEAD + """\
pre:
  - sC := 0
  - sN := 3
  - FOR sI := 1 TO sN DO sN := sN + 1; sC := sC + 1; END_FOR
"""
    assert run(text, [{}], ["sC", "sN"]) == [[3, 6]]


def test_for_must_not_write_its_variable() -> None:
    err = load_error(HEAD + "pre: ['FOR sI := 1 TO 3 DO sI := 2; END_FOR']\n")
    assert "the FOR loop must not write its variable 'sI'" in err.message


def test_methods_and_function_blocks() -> None:
    text = HEAD.replace("gsA: {initial: true}", 'gsA: {initial: true, actions: '
                        '["P1 timeT.Ini(30ms)"]}') + """\
transitions:
  - {from: gsA, to: gsB, when: "timeT.End()"}
pre:
  - sV := timeT.Val()
  - tonD(IN := iA, PT := 20ms)
  - sQ := tonD.Q
  - ctr(CU := ↑iB, R := FALSE, PV := 2)
  - oY := ctr.Q
  - sC := ctr.CV
  - sB.Set(1, iA AND iB)
"""
    scans = [(0, 0), (1, 0), (1, 0), (1, 1), (0, 0), (0, 1)]
    rows = run(text, [{"iA": a, "iB": b} for a, b in scans],
               ["sQ", "oY", "sC", "sB", "gsB.X", "sV"], cycle_ns=10 * MS)
    assert [r[:5] for r in rows] == [
        [False, False, 0, False, False],
        [False, False, 0, False, False],
        [False, False, 0, False, False],
        [True, False, 1, True, True],  # IN for 20 ms; first count; timer ended at 30 ms
        [False, False, 1, True, True],
        [False, True, 2, True, True],
    ]


def test_action_forms() -> None:
    text = HEAD.replace("gsA: {initial: true}", """gsA:
    initial: true
    actions:
      - N oX if iB
      - on ↑iA do sE := sE + 1
      - |
        P1
        sN := sN + 10
        sS := 5""") + """\
transitions:
  - {from: gsA, to: gsB, when: iN > 5}
  - {from: gsB, to: gsA, when: iN < 0}
"""
    scans = [{"iA": 0, "iB": 1}, {"iA": 1, "iB": 0}, {"iA": 1, "iB": 1}, {"iA": 0, "iN": 9},
             {"iA": 1}, {"iA": 0, "iN": -1}, {"iA": 1}]
    rows = run(text, scans, ["oX", "sE", "sN", "sS"])
    assert rows == [
        [True, 0, 10, 5],
        [False, 1, 10, 5],
        [True, 1, 10, 5],
        [False, 1, 10, 5],  # gsB active: the event action does not run
        [False, 1, 10, 5],
        [True, 1, 20, 5],  # back in gsA: P1 again
        [True, 2, 20, 5],
    ]


def test_for_with_a_zero_step_is_refused() -> None:
    err = load_error(HEAD + "pre: ['FOR sI := 1 TO 3 BY 0 DO sC := 1; END_FOR']\n")
    assert "expected a non-zero BY step" in err.message and "found '0'" in err.message
