"""Implicit typing (seed 000: the context decides), temporaries, typed signals."""

from __future__ import annotations

import pytest

from runtime.language import ast as A
from runtime.language.model import VarKind
from tests.language.langkit import MS, S, load_error, load_text, run

T = A.Type

HEAD = """\
grafcet: G
inputs: [iA, iB, iPieza, {iN: int}, {iNivel: real}]
outputs: [oX]
memory:
  sN: 0
  sB: false
  sR: 0.0
  sT: 0s
  sParo: false
steps:
  gsA: {initial: true}
  gsB: {}
"""


def chart(body: str) -> str:
    return HEAD + body


def pre_value(statement: str) -> A.Node:
    """Typed value of the single pre statement ``statement``."""
    g = load_text(chart(f"pre: [{statement!r}]\n".replace("'", '"')))
    node = g.pre[0].node
    assert isinstance(node, A.Assign)
    return node.value


# -- declarations -------------------------------------------------------------------------
def test_memory_types_come_from_initial_values() -> None:
    g = load_text(HEAD.replace("  sParo: false\n", """\
  sParo: false
  sTrue: TRUE
  sTime2: T#1m
  sRetained: {init: 7, retain: true}
"""))
    v = g.variables
    assert (v["sN"].type, v["sN"].init) == (T.INT, 0)
    assert (v["sB"].type, v["sB"].init) == (T.BOOL, False)
    assert (v["sR"].type, v["sR"].init) == (T.REAL, 0.0)
    assert (v["sT"].type, v["sT"].init) == (T.TIME, 0)
    assert (v["sTrue"].type, v["sTrue"].init) == (T.BOOL, True)
    assert (v["sTime2"].type, v["sTime2"].init) == (T.TIME, 60 * S)
    assert (v["sRetained"].type, v["sRetained"].retain) == (T.INT, True)


def test_typed_signals() -> None:
    g = load_text("""\
        grafcet: G
        inputs: [iA, {tTemperatura: int}, {iNivel: real}, {iRetardo: time}]
        outputs: [oX, {oConsigna: int}]
        memory: {sN: 0}
        steps: {gsA: {initial: true}}
        pre:
          - sN := sN + ↑(tTemperatura < -20)
          - oConsigna := tTemperatura * 2
    """)
    v = g.variables
    assert [(n, v[n].kind, v[n].type) for n in ("iA", "tTemperatura", "iNivel", "iRetardo",
                                                "oX", "oConsigna")] == [
        ("iA", VarKind.INPUT, T.BOOL), ("tTemperatura", VarKind.INPUT, T.INT),
        ("iNivel", VarKind.INPUT, T.REAL), ("iRetardo", VarKind.INPUT, T.TIME),
        ("oX", VarKind.OUTPUT, T.BOOL), ("oConsigna", VarKind.OUTPUT, T.INT)]


def test_unicode_identifiers() -> None:
    text = """\
        grafcet: Puerta
        inputs: [iParo, iPaño]
        outputs: [oAlarmaAvería]
        steps:
          gsParado: {initial: true}
          gsAvería: {actions: [oAlarmaAvería]}
        pre:
          - tAveríaAbrir := (gsParado.T >= 1s)·iPaño
        transitions:
          - {from: gsParado, to: gsAvería, when: tAveríaAbrir}
          - {from: gsAvería, to: gsParado, when: "iParo'"}
    """
    g = load_text(text)
    assert "gsAvería" in g.steps and g.variables["tAveríaAbrir"].type is T.BOOL
    rows = run(text, [{"iPaño": 1}] * 102, ["gsAvería.X", "oAlarmaAvería"], cycle_ns=10 * MS)
    assert rows[99] == [False, False]  # gsParado.T = 990 ms
    assert rows[100] == [True, True]  # 1 s: the transition fires and the action runs


# -- + and · are logical between bools, arithmetic otherwise -------------------------------
@pytest.mark.parametrize("text, op, typ", [
    ("tV := iA + iB", "OR", T.BOOL),
    ("tV := iA · iB", "AND", T.BOOL),
    ("tV := iA * iB", "AND", T.BOOL),
    ("tV := iA + sB", "OR", T.BOOL),
    ("tV := sN + 1", "ADD", T.INT),
    ("tV := sN · 2", "MUL", T.INT),
    ("tV := sN * sN", "MUL", T.INT),
    ("tV := iA + sN", "ADD", T.INT),  # a bool promotes to 0/1 beside a number
    ("tV := iA · iN", "MUL", T.INT),
    ("tV := sR + 1", "ADD", T.REAL),
    ("tV := sN + 2.5", "ADD", T.REAL),
    ("tV := iA + TRUE", "OR", T.BOOL),
    ("tV := iA · 1", "AND", T.BOOL),  # without a context wanting a number, 0/1 are bools
    ("tV := gsA.T + 5s", "ADD", T.TIME),
    ("tV := gsA.T * 2", "MUL", T.TIME),
    ("tV := sN - iA", "SUB", T.INT),
    ("tV := sN > 3", "GT", T.BOOL),
    ("tV := sN / 2", "DIV", T.INT),
    ("tV := sR / 2", "DIV", T.REAL),
    ("tV := iA XOR iB", "XOR", T.BOOL),
    ("tV := -iA", "NEG", T.INT),
])
def test_operator_meaning_depends_on_types(text: str, op: str, typ: A.Type) -> None:
    n = pre_value(text)
    assert n.type is typ
    assert isinstance(n, (A.Unary, A.Binary))
    assert n.op == op


def test_temporary_typed_by_use() -> None:
    g = load_text(chart("""\
pre:
  - tB := iA·iB'
  - tN := sN + 1
  - tR := sR * 2
  - tT := gsA.T
  - tC := gsA.T >= 10s
  - tInt := 0
  - tTrue := TRUE
  - tFromTemp := tN * 2
"""))
    types = {n: g.variables[n].type for n in ("tB", "tN", "tR", "tT", "tC", "tInt", "tTrue",
                                               "tFromTemp")}
    assert types == {"tB": T.BOOL, "tN": T.INT, "tR": T.REAL, "tT": T.TIME, "tC": T.BOOL,
                     "tInt": T.INT, "tTrue": T.BOOL, "tFromTemp": T.INT}
    assert all(g.variables[n].kind is VarKind.TEMP for n in types)


def test_temporary_typed_by_first_assignment_in_file_order() -> None:
    g = load_text(chart("""\
pre:
  - tX := 0
post:
  - tX := iA
"""))
    assert g.variables["tX"].type is T.INT  # iA then counts as 0/1
    g = load_text(HEAD.replace("steps:", "pre: [tX := iA]\nsteps:") + "post: [tX := 1]\n")
    assert g.variables["tX"].type is T.BOOL
    # a use before the assignment (in file order) does not decide the type
    g = load_text(chart("""\
transitions:
  - {from: gsA, to: gsB, when: tLater}
post:
  - tLater := iA AND iB
"""))
    assert g.variables["tLater"].type is T.BOOL


def test_temporary_typed_from_another_temporary_assigned_later() -> None:
    g = load_text(chart("""\
pre:
  - tA := tB + 1
  - tB := sN * 2
"""))
    assert g.variables["tA"].type is T.INT and g.variables["tB"].type is T.INT


def test_temporary_set_latches_a_bool() -> None:
    g = load_text(chart("pre: ['tL.Set(1, iA)', 'oX := tL']\n"))
    assert g.variables["tL"].type is T.BOOL


def test_temporary_with_conflicting_assignments() -> None:
    err = load_error(chart("pre: ['tX := iA', 'tX := 2.5']\n"))
    assert "expected a bool value for 'tX', found real '2.5'" in err.message


def test_temporaries_in_a_cycle_have_no_type() -> None:
    err = load_error(chart("pre: ['tA := tB', 'tB := tA']\n"))
    assert "cannot decide the type of temporary" in err.message


# -- bools promote to 0/1; 0/1 are bools where a bool is wanted ------------------------------
def test_counting_rising_edges() -> None:
    rows = run(chart("post: ['sN := sN + ↑iPieza']\n"),
               [{"iPieza": v} for v in (0, 1, 1, 0, 1, 0, 0, 1)], ["sN"])
    assert [r[0] for r in rows] == [0, 1, 1, 1, 2, 2, 2, 3]


def test_seed_counter_of_cold_events() -> None:
    text = """\
        grafcet: G
        inputs: [{tTemperatura: int}]
        outputs: []
        memory: {s1: 0}
        steps: {gsA: {initial: true}}
        post: ['s1 := s1+↑(tTemperatura < -20)']
    """
    temps = (0, -25, -30, -10, -21, 5, -40)
    rows = run(text, [{"tTemperatura": t} for t in temps], ["s1"])
    assert [r[0] for r in rows] == [0, 1, 1, 1, 2, 2, 3]


def test_zero_and_one_as_bool_constants() -> None:
    text = chart("""\
pre:
  - sParo.Set(1, iA)
  - sB := 1
transitions:
  - {from: gsA, to: gsB, when: "1"}
  - {from: gsB, to: gsA, when: 0}
""")
    g = load_text(text)
    assert g.variables["sB"].type is T.BOOL
    assert g.transitions[0].cond.type is T.BOOL
    rows = run(text, [{"iA": 0}, {"iA": 1}, {"iA": 0}], ["sParo", "sB", "gsB.X"])
    assert rows == [[False, True, False], [True, True, True], [True, True, True]]


def test_bool_plus_literal_takes_the_type_the_context_wants() -> None:
    text = chart("""\
memory: {sN: 0, sM: 0, sQ: false}
pre:
  - sN := iA + 1
  - sM := (iA + 1) * 3
  - sQ := (iA + 1) >= 2
  - tL := iA + 1
""").replace("memory:\n  sN: 0\n  sB: false\n  sR: 0.0\n  sT: 0s\n  sParo: false\n", "")
    rows = run(text, [{"iA": 0}, {"iA": 1}], ["sN", "sM", "sQ", "tL"])
    assert rows == [[1, 3, False, True], [2, 6, True, True]]


def test_integer_arithmetic_follows_iec() -> None:
    text = chart("""\
memory: {sQ: 0, sM: 0, sQ2: 0, sM2: 0, sF: 0.0}
pre:
  - sQ := iN / 4
  - sM := iN MOD 4
  - sQ2 := iN / -4
  - sM2 := iN MOD -4
  - sF := iN / 4
""").replace("memory:\n  sN: 0\n  sB: false\n  sR: 0.0\n  sT: 0s\n  sParo: false\n", "")
    rows = run(text, [{"iN": 7}, {"iN": -7}], ["sQ", "sM", "sQ2", "sM2", "sF"])
    assert rows == [[1, 3, -1, 3, 1.0], [-1, -3, 1, -3, -1.0]]


def test_real_and_time_arithmetic() -> None:
    text = chart("""\
pre:
  - sR := iNivel * 2 + 1
  - sT := T#1h30m + 250ms * 2 - 1s / 4
""")
    rows = run(text, [{"iNivel": 1.25}], ["sR", "sT"])
    assert rows == [[3.5, 90 * 60 * S + 500 * MS - 250 * MS]]


# -- type errors ----------------------------------------------------------------------------
@pytest.mark.parametrize("statement, words", [
    ("tX := iA + 3 >= gsA.T", ["type error", "expected a time", "found int 'iA + 3'",
                               "gsA.T"]),
    ("sB := sN", ["expected a bool value for 'sB'", "found int 'sN'"]),
    ("sN := sR", ["expected an int value for 'sN'", "found real 'sR'"]),
    ("sN := sN MOD 2.5", ["expected integers for MOD", "found real '2.5'"]),
    ("tX := NOT sN", ["expected a bool operand of NOT", "found int 'sN'"]),
    ("tX := sN'", ["expected a bool operand of postfix '", "found int 'sN'"]),
    ("tX := ↑sN", ["expected a bool operand of ↑", "found int 'sN'"]),
    ("tX := iA AND 5", ["expected a bool operand of AND", "found int '5'"]),
    ("tX := gsA.T + 5", ["expected numbers, or times", "found time 'gsA.T' and int '5'"]),
    ("sT := gsA.T * gsB.T", ["found time 'gsA.T' and time 'gsB.T'"]),
    ("iA := 1", ["expected an output, memory or temporary", "found input 'iA'"]),
    ("FirstScan := 1", ["found system value 'FirstScan'"]),
    ("tX := 2 + gsA", ["step 'gsA' is not a variable", "gsA.X"]),
])
def test_type_errors(statement: str, words: list[str]) -> None:
    err = load_error(chart(f"pre: [\"{statement}\"]\n"))
    for w in words:
        assert w in err.message, err.message


def test_a_transition_condition_must_be_bool() -> None:
    err = load_error(chart('transitions: [{from: gsA, to: gsB, when: "sN + 2"}]\n'))
    assert "expected a bool, found int 'sN + 2'" in err.message
    err = load_error(chart('transitions: [{from: gsA, to: gsB, when: "2"}]\n'))
    assert "expected a bool, found int '2'" in err.message


def test_yaml_numbers_and_bools_as_conditions() -> None:
    g = load_text(chart("""\
transitions:
  - {from: gsA, to: gsB, when: 1}
  - {from: gsB, to: gsA, when: true}
"""))
    assert [t.cond.type for t in g.transitions] == [T.BOOL, T.BOOL]
    assert run(chart("transitions: [{from: gsA, to: gsB, when: true}]\n"), [{}, {}],
               ["gsB.X"]) == [[False], [True]]
