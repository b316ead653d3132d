"""Errors in users' files: exact FILE:LINE:COL and the key words of the message."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.language.langkit import assert_error, file_error, where, write

ROOT = Path(__file__).resolve().parents[2]

HEAD = """\
grafcet: DrawerTester
inputs: [iParo, iMarcha, iAbierto, iCerrado]
outputs: [oAbrir, oCerrar, oParado, oTest]
memory:
  sParo: false
  sCierres: {init: 0, retain: true}
timers: [timeTest]
blocks:
  tonDoor: TON
"""

STEPS = """\
steps:
  gsParado: {initial: true, actions: [oParado]}
  gsAbrir:  {actions: [oAbrir, oTest]}
  gsCerrar: {actions: [oCerrar, oTest]}
"""


def check(tmp_path: Path, text: str, needle: str, *words: str, nth: int = 0,
          plus: int = 0) -> None:
    """Loading ``text`` fails at the place of ``needle`` with a message holding ``words``."""
    path = write(tmp_path, "chart.yaml", text)
    assert_error(file_error(path), path, where(text, needle, nth, plus), *words)


def when(cond: str) -> str:
    """A chart whose first transition has the condition ``cond`` (a plain scalar)."""
    return HEAD + STEPS + f"transitions:\n  - {{from: gsParado, to: gsAbrir, when: {cond}}}\n"


# -- YAML and keys ------------------------------------------------------------------------
def test_yaml_syntax_error(tmp_path: Path) -> None:
    text = HEAD + "steps:\n  gsParado: {initial: true\ntransitions: []\n"
    check(tmp_path, text, ": []", "YAML syntax", "expected ',' or '}'", "got ':'")


def test_yaml_mapping_value_not_allowed(tmp_path: Path) -> None:
    text = HEAD.replace("grafcet: DrawerTester", "grafcet: DrawerTester\ndescription: a: b")
    check(tmp_path, text, ": b", "YAML syntax", "found ': b'",
          "quote the whole value: description: \"a: b\"")


def test_statement_read_as_a_mapping_by_yaml(tmp_path: Path) -> None:
    text = HEAD + STEPS + "post:\n  - CASE sCierres OF 1: oTest := 1; END_CASE\n"
    check(tmp_path, text, "CASE", "expected a statement, found a mapping",
          "quote the text or use a block scalar")


def test_duplicate_key(tmp_path: Path) -> None:
    text = HEAD + STEPS + "  gsAbrir: {}\n"
    check(tmp_path, text, "gsAbrir", "duplicate key", "expected each key once",
          "found 'gsAbrir'", nth=1)


@pytest.mark.parametrize("text, needle, words", [
    (HEAD + STEPS + "trasitions: []\n", "trasitions",
     ["unknown key 'trasitions' in a grafcet file", "expected one of",
      "(did you mean 'transitions'?)"]),
    (HEAD + STEPS.replace("{initial: true,", "{inital: true,"), "inital",
     ["unknown key 'inital' in step 'gsParado'", "(did you mean 'initial'?)"]),
    (HEAD + STEPS + "transitions:\n  - {from: gsParado, to: gsAbrir, wen: iMarcha}\n", "wen",
     ["unknown key 'wen' in a transition", "(did you mean 'when'?)"]),
    (HEAD.replace("retain: true", "retian: true") + STEPS, "retian",
     ["unknown key 'retian' in memory 'sCierres'", "(did you mean 'retain'?)"]),
])
def test_unknown_key_with_suggestion(tmp_path: Path, text: str, needle: str,
                                     words: list[str]) -> None:
    check(tmp_path, text, needle, *words)


# -- unknown names -------------------------------------------------------------------------
@pytest.mark.parametrize("cond, needle, words", [
    ('"iMarca·iParo\'"', "iMarca", ["unknown variable 'iMarca'",
                                    "(did you mean 'iMarcha'?)"]),
    ('"iParo + gsAbrr.X"', "gsAbrr", ["unknown step 'gsAbrr'", "(did you mean 'gsAbrir'?)"]),
    ('"timeTst.End()"', "timeTst", ["unknown timer 'timeTst'", "(did you mean 'timeTest'?)"]),
    ('"tonDor.Q"', "tonDor", ["unknown function block 'tonDor'",
                              "(did you mean 'tonDoor'?)"]),
    ("tonDoor.QQ", "tonDoor", ["TON 'tonDoor' has no member 'QQ'", "expected one of",
                               "Q ET"]),
    ('"timeTest.Ended()"', "timeTest", ["timer 'timeTest' has no method 'Ended'",
                                        "expected Ini End Reset Val"]),
    ("timeTest.End", "timeTest", ["expected a call timeTest.End()", "found timeTest.End"]),
    ("gsAbrir", "gsAbrir", ["step 'gsAbrir' is not a variable", "gsAbrir.X"]),
    ("iParo.X", "iParo", ["unknown step 'iParo'", "a variable, not a step"]),
])
def test_unknown_names_in_a_condition(tmp_path: Path, cond: str, needle: str,
                                      words: list[str]) -> None:
    text = when(cond)
    check(tmp_path, text, needle, *words, nth=text.count(needle) - 1)


def test_unknown_block_in_a_call(tmp_path: Path) -> None:
    text = HEAD + STEPS + "pre:\n  - tonDor(IN := iMarcha, PT := 5s)\n"
    check(tmp_path, text, "tonDor(", "unknown function block 'tonDor'",
          "(did you mean 'tonDoor'?)")


def test_unknown_block_input(tmp_path: Path) -> None:
    text = HEAD + STEPS + "pre:\n  - tonDoor(IN := iMarcha, PX := 5s)\n"
    check(tmp_path, text, "5s", "TON 'tonDoor' has no input 'PX'", "expected one of IN PT")


def test_unknown_assigned_name_must_be_a_temporary(tmp_path: Path) -> None:
    text = HEAD + STEPS + "pre:\n  - sCierre := 1\n"
    check(tmp_path, text, "sCierre :=", "unknown variable 'sCierre'",
          "(did you mean 'sCierres'?)", "expected a declared output or memory variable",
          "'t' and a capital letter")


def test_unknown_action_target(tmp_path: Path) -> None:
    text = HEAD + STEPS.replace("[oAbrir, oTest]", "[oAbir, oTest]")
    check(tmp_path, text, "oAbir", "unknown variable 'oAbir'", "(did you mean 'oAbrir'?)")


@pytest.mark.parametrize("key, needle", [("from", "gsAbierto"), ("to", "gsCerar")])
def test_transition_naming_an_unknown_step(tmp_path: Path, key: str, needle: str) -> None:
    text = HEAD + STEPS + (
        "transitions:\n"
        "  - {from: gsParado, to: gsAbrir, when: iMarcha}\n"
        "  - {from: gsAbierto, to: gsCerrar, when: iAbierto}\n"
        "  - from: [gsCerrar, gsAbrir]\n"
        "    to: [gsParado, gsCerar]\n"
        "    when: iCerrado\n")
    if key == "from":
        check(tmp_path, text, needle, "unknown step 'gsAbierto'", "'from'",
              "(did you mean 'gsAbrir'?)", "expected a step")
    else:
        text = text.replace("gsAbierto", "gsAbrir")
        check(tmp_path, text, needle, "unknown step 'gsCerar'", "'to'",
              "(did you mean 'gsCerrar'?)")


def test_chart_without_an_initial_step(tmp_path: Path) -> None:
    text = HEAD + STEPS.replace("{initial: true, ", "{")
    check(tmp_path, text, "steps:", "no initial step", "initial: true")


# -- parentheses, time literals ------------------------------------------------------------
def test_unbalanced_parentheses_missing_close(tmp_path: Path) -> None:
    text = when('"iParo + (iMarcha·(iAbierto + iCerrado)"')
    path = write(tmp_path, "chart.yaml", text)
    err = file_error(path)
    line, col = where(text, "iCerrado)", plus=len("iCerrado)"))
    opened_line, opened_col = where(text, "(iMarcha")
    assert_error(err, path, (line, col), "unbalanced parentheses", "expected ')'",
                 f"opened at line {opened_line}, column {opened_col}", "found end of text")


def test_unbalanced_parentheses_extra_close(tmp_path: Path) -> None:
    check(tmp_path, when('"(iParo + iMarcha))·iAbierto"'), "))", "unbalanced parentheses",
          "found ')' without a matching '('", plus=1)


def test_unbalanced_parentheses_in_a_call(tmp_path: Path) -> None:
    text = HEAD + STEPS + "pre:\n  - tonDoor(IN := iMarcha, PT := 5s\n  - oTest := 1\n"
    check(tmp_path, text, "5s", "unbalanced parentheses", "expected ',' or ')'",
          "found end of text", plus=2)


@pytest.mark.parametrize("cond, needle", [
    ('"gsAbrir.T >= 10x"', "10x"),
    ('"gsAbrir.T >= 1s10m"', "1s10m"),
    ('"gsAbrir.T >= T#5q"', "T#5q"),
    ('"gsAbrir.T >= 10 s"', "10 s"),
])
def test_bad_time_literal(tmp_path: Path, cond: str, needle: str) -> None:
    text = when(cond)
    if needle == "10 s":  # a number, a space and a unit: the newcomer's time literal
        check(tmp_path, text, needle, "expected a time literal without a space", "(10s, or "
              "T#10s), found '10 s'")
    else:
        check(tmp_path, text, needle, f"bad time literal '{needle}'", "expected",
              "units in order")


def test_bad_time_in_a_yaml_value(tmp_path: Path) -> None:
    text = HEAD + STEPS.replace("gsAbrir:  {", "gsAbrir:  {max: 10x, ")
    check(tmp_path, text, "10x", "bad time literal '10x' for max of step 'gsAbrir'",
          "expected e.g. 10s")


# -- actions --------------------------------------------------------------------------------
@pytest.mark.parametrize("act, needle, words", [
    ("X oAbrir", "X oAbrir", ["unknown qualifier 'X'", "expected one of N S R L D P P1 P0"]),
    ("Q1 oAbrir", "Q1", ["unknown qualifier 'Q1'"]),
    ("L oAbrir", "oAbrir", ["expected a time after qualifier L", "found 'oAbrir'"]),
    ("D oAbrir", "oAbrir", ["expected a time after qualifier D"]),
    ("SD oAbrir", "oAbrir", ["expected a time after qualifier SD"]),
    ("D 500 oAbrir", "500", ["expected a time after qualifier D", "found '500'"]),
    ("N 2s oAbrir", "2s", ["only L D DS SD SL take a time", "found the time '2s'"]),
    ("P1 oAbrir", "oAbrir", ["expected statements after P1", "found the bare variable "
                             "'oAbrir'", "rule I.6"]),
    ("P0 oAbrir", "oAbrir", ["expected statements after P0", "found the bare variable"]),
    ("on ↑iMarcha do oAbrir", "oAbrir", ["expected statements after 'do'",
                                        "found the bare variable 'oAbrir'"]),
    ("on iMarcha do sParo := 1", "iMarcha", ["expected an edge", "found 'iMarcha'"]),
    ("N oAbrir if ↑iMarcha", "↑iMarcha", ["expected a condition without edges",
                                          "found '↑iMarcha'", "on EVENT do"]),
    ("S sParo := 1", "S sParo", ["expected a bool variable after S", "found statements"]),
    ("sCierres", "sCierres", ["expected a bool variable", "found int 'sCierres'"]),
    ("iParo", "iParo", ["expected an output or memory variable", "found input 'iParo'"]),
])
def test_action_errors(tmp_path: Path, act: str, needle: str, words: list[str]) -> None:
    text = HEAD + STEPS.replace("[oAbrir, oTest]", f"[oTest, \"{act}\"]")
    line, _ = where(text, f'"{act}"')
    _, col = where(text, needle, nth=text.count(needle) - 1)
    path = write(tmp_path, "chart.yaml", text)
    assert_error(file_error(path), path, (line, col), *words)


# -- type errors ------------------------------------------------------------------------------
def test_type_error_time_against_int(tmp_path: Path) -> None:
    check(tmp_path, when('"iMarcha + 3 >= gsAbrir.T"'), "iMarcha + 3", "type error",
          "expected a time to compare with time 'gsAbrir.T'", "found int 'iMarcha + 3'")


def test_type_error_in_a_statement(tmp_path: Path) -> None:
    text = HEAD + STEPS + "pre:\n  - sParo := sCierres + 1\n"
    check(tmp_path, text, "sCierres + 1", "type error", "expected a bool value for 'sParo'",
          "found int 'sCierres + 1'")


# -- columns inside plain, quoted and block scalars ------------------------------------------
def test_column_in_a_plain_scalar(tmp_path: Path) -> None:
    check(tmp_path, when("iParo·iMarca"), "iMarca", "unknown variable 'iMarca'")


def test_column_in_a_single_quoted_scalar_with_escaped_quote(tmp_path: Path) -> None:
    # YAML writes the seed's ' as '' inside single quotes: columns stay the file's
    check(tmp_path, when("'iParo''·iMarca'"), "iMarca", "unknown variable 'iMarca'")


def test_column_in_a_double_quoted_scalar_with_escapes(tmp_path: Path) -> None:
    check(tmp_path, when('"\\u2191iParo·iMarca"'), "iMarca", "unknown variable 'iMarca'")


def test_column_in_a_literal_block_scalar(tmp_path: Path) -> None:
    text = HEAD + STEPS + textwrap.dedent("""\
        pre:
          - |
            IF iParo THEN
              sParo := 1
            ELSIF iMarcha THEN
                sParo := sCierres + 1
            END_IF
        """)
    check(tmp_path, text, "sCierres + 1", "type error", "found int 'sCierres + 1'")


def test_column_in_a_folded_block_scalar(tmp_path: Path) -> None:
    text = HEAD + STEPS + textwrap.dedent("""\
        transitions:
          - from: gsParado
            to: gsAbrir
            when: >
              iParo AND
              iMarca
        """)
    check(tmp_path, text, "iMarca\n", "unknown variable 'iMarca'")


def test_column_in_a_multi_line_plain_scalar(tmp_path: Path) -> None:
    text = HEAD + STEPS + textwrap.dedent("""\
        transitions:
          - from: gsParado
            to: gsAbrir
            when: iParo AND
              (iMarca OR iCerrado)
        """)
    check(tmp_path, text, "iMarca ", "unknown variable 'iMarca'")


def test_end_of_text_points_after_the_last_character(tmp_path: Path) -> None:
    text = HEAD + STEPS + textwrap.dedent("""\
        post:
          - |
            oTest := iParo +
        """)
    check(tmp_path, text, "+\n", "expected an operand", "found end of text", plus=1)


def test_error_in_an_action_list_item(tmp_path: Path) -> None:
    text = HEAD + textwrap.dedent("""\
        steps:
          gsParado: {initial: true}
          gsCerrar:
            actions:
              - oCerrar
              - P1 sCierres := sCierres + (1
        """)
    check(tmp_path, text, "(1", "unbalanced parentheses", "found end of text", plus=2)


# -- plant files --------------------------------------------------------------------------------
PLANT = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  tester1:
    grafcet: chart.yaml
    inputs:
      iParo: {from: sim.I0, invert: true}
      iMarcha: sim.I1
      iAbierto: sim.I2
      iCerrado: sim.I3
    outputs: {oAbrir: sim.Q0, oCerrar: sim.Q1, oParado: sim.Q2, oTest: sim.Q3}
"""


def plant_check(tmp_path: Path, plant: str, needle: str, *words: str, nth: int = 0) -> None:
    write(tmp_path, "chart.yaml", HEAD + STEPS)
    path = write(tmp_path, "plant.yaml", plant)
    assert_error(file_error(path), path, where(plant, needle, nth), *words)


def test_plant_ok(tmp_path: Path) -> None:
    from runtime.language.plantfile import load_plant

    write(tmp_path, "chart.yaml", HEAD + STEPS)
    p = load_plant(write(tmp_path, "plant.yaml", PLANT))
    assert list(p.instances) == ["tester1"]


def test_instance_leaves_an_input_unbound(tmp_path: Path) -> None:
    plant_check(tmp_path, PLANT.replace("      iCerrado: sim.I3\n", ""), "inputs:",
                "instance 'tester1' leaves input 'iCerrado' of grafcet DrawerTester unbound",
                "expected a binding", "found none")


def test_instance_leaves_an_output_unbound(tmp_path: Path) -> None:
    plant_check(tmp_path, PLANT.replace(", oTest: sim.Q3", ""), "outputs:",
                "leaves output 'oTest'", "unbound")


def test_physical_output_bound_twice(tmp_path: Path) -> None:
    plant_check(tmp_path, PLANT.replace("oTest: sim.Q3", "oTest: sim.Q1"), "sim.Q1",
                "physical output 'sim.Q1' is bound twice", "tester1.oTest", "tester1.oCerrar",
                nth=1)


def test_physical_output_bound_twice_by_two_instances(tmp_path: Path) -> None:
    second = PLANT.split("instances:\n")[1].replace("tester1", "tester2").replace(
        "sim.I", "sim.I1").replace("sim.Q0", "sim.Q10").replace("sim.Q1,", "sim.Q11,").replace(
        "sim.Q2", "sim.Q12")
    plant = PLANT + second
    plant_check(tmp_path, plant, "sim.Q3", "physical output 'sim.Q3' is bound twice",
                "tester2.oTest", "tester1.oTest", nth=1)


def test_binding_an_unknown_signal(tmp_path: Path) -> None:
    plant_check(tmp_path, PLANT.replace("iMarcha: sim.I1", "iMarca: sim.I1"), "iMarca",
                "'iMarca' is not an input of grafcet DrawerTester", "(did you mean 'iMarcha'?)")


def test_binding_an_unknown_driver(tmp_path: Path) -> None:
    plant_check(tmp_path, PLANT.replace("iMarcha: sim.I1", "iMarcha: sin.I1"), "sin.I1",
                "unknown driver or instance 'sin'", "(did you mean 'sim'?)")


def test_output_bound_to_another_instance(tmp_path: Path) -> None:
    plant = PLANT + PLANT.split("instances:\n")[1].replace("tester1", "tester2").replace(
        "oAbrir: sim.Q0", "oAbrir: tester1.oAbrir").replace("sim.Q", "sim.Q1").replace(
        "sim.I", "sim.I1")
    plant_check(tmp_path, plant, "tester1.oAbrir", "expected a driver point for output "
                "'oAbrir'", "found instance 'tester1'")


def test_unknown_plant_key(tmp_path: Path) -> None:
    plant_check(tmp_path, PLANT.replace("instances:", "instancse:"), "instancse",
                "unknown key 'instancse' in a plant file", "(did you mean 'instances'?)")


def test_error_in_the_chart_of_a_plant_names_the_chart(tmp_path: Path) -> None:
    chart = when('"iMarca"')
    cpath = write(tmp_path, "chart.yaml", chart)
    path = write(tmp_path, "plant.yaml", PLANT)
    assert_error(file_error(path), cpath, where(chart, "iMarca\""), "unknown variable")


# -- the command line -----------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["chart", "plant"])
def test_cli_reports_one_line_and_exit_status_2(tmp_path: Path, kind: str) -> None:
    chart = when('"iMarcha + 3 >= gsAbrir.T"')
    cpath = write(tmp_path, "chart.yaml", chart)
    target = cpath if kind == "chart" else write(tmp_path, "plant.yaml", PLANT)
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "compile", target],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    line, col = where(chart, "iMarcha + 3")
    assert lines[0].startswith(f"{cpath}:{line}:{col}: error: type error: expected a time")
    assert proc.stdout == ""


def test_cli_compiles_a_good_chart(tmp_path: Path) -> None:
    text = HEAD + STEPS + textwrap.dedent("""\
        transitions:
          - {from: gsParado, to: gsAbrir, when: "↑iMarcha·iParo'"}
        """)
    path = write(tmp_path, "chart.yaml", text)
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "compile", path],
                          capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "ok: DrawerTester" in proc.stderr


# -- statements and names ----------------------------------------------------------------------
@pytest.mark.parametrize("statement, needle, words", [
    ("sCierres = 1", "= 1", ["expected ':=' or a call after 'sCierres'", "found '='"]),
    ("sCierres := 1 2", "1 |2", ["expected ';' or a new line between statements",
                                "found '2'"]),
    ("sCierres := 1 + * 2", "* 2", ["expected an operand", "found '*'"]),
    ("sCierres := 5 @ 3", "@", ["found the unexpected character '@'"]),
    ("IF iParo THEN sCierres := 1", "1|\"", ["expected ELSIF, ELSE or END_IF",
                                          "found end of text"]),
    ("WHILE iParo DO sCierres := 1; END_WHILE", "WHILE i", ["expected a statement",
                                                          "found WHILE", "not allowed",
                                                          "bounded FOR loop"]),
    ("CASE sCierres OF 1: oTest := 1; 5..3: oTest := 0; END_CASE", "5..3",
     ["expected a CASE range low..high", "found 5..3"]),
    ("CASE sCierres OF 1..4: oTest := 1; 3: oTest := 0; END_CASE", "3:",
     ["expected each CASE value in one label only", "found 3", "earlier label 1..4"]),
    ("CASE sCierres OF 1: oTest := 1; 2 oTest := 0; END_CASE", "oTest := 0",
     ["expected ':' after the CASE labels", "found 'oTest'"]),
    ("CASE sCierres OF 1: oTest := 1; -1: oTest := 0; ELSE END_CASE", "", []),
    ("tA² := 1", "tA²", ["expected a name of letters, digits and '_'", "found 'tA²'"]),
    ("timeTest.Ini(5)", "5)", ["type error", "expected a time for timeTest.Ini",
                               "found int '5'"]),
    ("sParo.Set(1)", "sParo", ["expected 2 arguments (value, condition) for sParo.Set",
                               "found 1"]),
    ("oTest := timeTest.Reset()", "timeTest", ["expected a value",
                                               "found the statement timeTest.Reset()"]),
])
def test_statement_errors(tmp_path: Path, statement: str, needle: str,
                          words: list[str]) -> None:
    text = HEAD + STEPS + f'pre:\n  - "{statement}"\n'
    if not needle:  # a correct statement
        from tests.language.langkit import load_text

        load_text(text)
        return
    before, _, after = needle.rpartition("|")  # '|' marks the column inside the needle
    needle = before + after
    check(tmp_path, text, needle, *words, nth=text.count(needle) - 1, plus=len(before))


@pytest.mark.parametrize("name, words", [
    ("iA²", ["expected a name for an input (letters, digits, '_')", "found 'iA²'"]),
    ("a·b", ["expected a name for an input", "found 'a·b'"]),
    ("RE", ["expected a name for an input, found the keyword 'RE'"]),
    ("SFCPause", ["'SFCPause' is a built-in name"]),
    ("iParo", ["'iParo' is declared twice"]),
])
def test_declared_name_errors(tmp_path: Path, name: str, words: list[str]) -> None:
    text = HEAD.replace("iCerrado]", f"iCerrado, {name}]") + STEPS
    check(tmp_path, text, name, *words, nth=text.count(name) - 1,
          plus=0)


@pytest.mark.parametrize("statement, words", [
    ("oTest := " + "(" * 60 + "iParo" + ")" * 60,
     ["expected at most 50 nested parentheses or prefix operators", "found more"]),
    ("oTest := " + "NOT " * 60 + "iParo",
     ["expected at most 50 nested parentheses or prefix operators"]),
    ("oTest := " + " + ".join(["iParo"] * 500),
     ["expected at most 100 operators in a chain", "split the expression with temporaries"]),
    ("IF iParo THEN " * 20 + "oTest := 1; " + "END_IF; " * 20,
     ["expected at most 16 IF, CASE or FOR statements inside one another"]),
])
def test_limits_give_errors_not_crashes(tmp_path: Path, statement: str,
                                        words: list[str]) -> None:
    """Absurdly deep text is refused cleanly (the checker, the compiler and Python's own
    parser have depth limits); the limits are far beyond hand-written charts."""
    text = HEAD + STEPS + f'pre:\n  - "{statement}"\n'
    path = write(tmp_path, "chart.yaml", text)
    err = file_error(path)
    assert err.loc.file == path and err.loc.line == text.count("\n")
    for w in words:
        assert w in err.message


def test_limits_leave_room_for_real_charts() -> None:
    from tests.language.langkit import load_text

    deep = "(" * 49 + " AND ".join(["NOT iParo"] * 50) + ")" * 49
    loops = "".join(f"FOR t{i} := 1 TO 1 DO " for i in range(16)) + f"oTest := {deep}; " + \
        "END_FOR; " * 16
    chain = " + ".join(["iParo"] * 101)
    g = load_text(HEAD + STEPS + f'pre:\n  - "{loops}"\npost:\n  - "oTest := {chain}"\n')
    from runtime.compiler.codegen import compile_grafcet
    from runtime.engine.instance import Instance

    inst = Instance("deep", compile_grafcet(g))
    inst.set("iParo", True)
    inst.scan(10**9, 0)
    assert inst.get("oTest") is True


def test_yaml_1_2_booleans_yes_no_on_off_are_text(tmp_path: Path) -> None:
    from runtime.language.grafcetfile import load_grafcet

    g = load_grafcet(write(tmp_path, "ok.yaml", """\
        grafcet: Names
        inputs: [On, off, yes]
        outputs: [No]
        steps:
          s0: {initial: true, actions: [No]}
        transitions:
          - {from: s0, to: s0, when: On AND NOT off AND yes}
        """))
    assert [v.name for v in g.inputs] == ["On", "off", "yes"]
    assert g.steps["s0"].actions[0].target == "No"
    check(tmp_path, HEAD.replace("retain: true", "retain: yes") + STEPS, "yes",
          "expected true or false for retain", "found the text 'yes'")


def test_an_instance_name_python_would_normalise_is_a_source_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """'probador_nº1' is 'probador_no1' to Python (NFKC): the plant cycle failed with a
    NameError at start-up; now the plant file says so at the instance's line."""
    from runtime.errors import SourceError
    from runtime.language.plantfile import load_plant

    root = Path(__file__).resolve().parents[2] / "configs" / "drawer_tester"
    text = (root / "plant_sim.yaml").read_text(encoding="utf-8").replace(
        "grafcet: ", f"grafcet: {root}/").replace("tester1:", "probador_nº1:")
    (tmp_path / "p.yaml").write_text(text, encoding="utf-8")
    with pytest.raises(SourceError, match="canonical form") as err:
        load_plant(str(tmp_path / "p.yaml"))
    assert "probador_nº1" in str(err.value)
