"""Issue 13 §10: the messages a newcomer trips over, through ``softplc compile``.

Each chart is the kind a user writes from the course exercises, with the one slip a
newcomer makes; the test asserts the whole line, ``FILE:LINE:COL: error: MESSAGE``, so
that the place and the advice both stay as written.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.cli import main
from tests.language.langkit import where, write

MOTOR = """\
grafcet: Arranque1
inputs: [iMarcha, iParo]
outputs: [oMotor]
steps:
  Ini: {initial: true}
  Arranque: {actions: [oMotor]}
transitions:
  - {from: Ini, to: Arranque, when: iMarcha}
  - {from: Arranque, to: Ini, when: WHEN}
"""


def compile_error(tmp_path: Path, capsys: pytest.CaptureFixture[str], text: str) -> str:
    """``softplc compile`` on ``text``: exit 2, nothing on stdout, one line on stderr."""
    path = write(tmp_path, "chart.yaml", text)
    rc = main(["compile", path])
    out, err = capsys.readouterr()
    assert (rc, out) == (2, ""), err
    assert len(err.splitlines()) == 1, err
    return err.rstrip("\n")


def line(tmp_path: Path, text: str, needle: str, message: str, nth: int = 0) -> str:
    at_line, col = where(text, needle, nth)
    return f"{tmp_path / 'chart.yaml'}:{at_line}:{col}: error: {message}"


# -- a time literal with a space -------------------------------------------------------------
@pytest.mark.parametrize("cond, written, fixed", [
    ("Arranque.T >= 5 s", "5 s", "5s"),
    ("Arranque.T >= 250 ms AND iParo", "250 ms", "250ms"),
    ("Arranque.T >= 1.5 s", "1.5 s", "1.5s"),
])
def test_time_literal_with_a_space(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                   cond: str, written: str, fixed: str) -> None:
    text = MOTOR.replace("WHEN", cond)
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, written,
        f"expected a time literal without a space between the number and its unit "
        f"({fixed}, or T#{fixed}), found '{written}'")


def test_time_literal_with_a_space_in_a_statement(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace("outputs: [oMotor]",
                                                  "outputs: [oMotor]\nmemory: {sT: 0s}")
    text += "post:\n  - sT := 2 s\n"
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "2 s", "expected a time literal without a space between the number "
                               "and its unit (2s, or T#2s), found '2 s'")


def test_time_literal_with_a_space_after_a_timed_qualifier(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace("actions: [oMotor]",
                                                  "actions: [D 3 s oMotor]")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "3 s", "expected a time literal without a space between the number "
                               "and its unit (3s, or T#3s), found '3 s'")


def test_time_value_in_yaml_with_a_space(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace("{actions: [oMotor]}",
                                                  "{actions: [oMotor], max: 10 s}")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "10 s", "expected a time literal without a space between the number "
                                "and its unit (10s, or T#10s), found '10 s' for max of step "
                                "'Arranque'")


def test_a_number_then_a_name_is_still_an_operator_error(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Near miss: a word that is no time unit keeps the plain message."""
    text = MOTOR.replace("WHEN", "Arranque.T >= 5 iParo")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "iParo}", "expected an operator or the end of the expression, found "
                                  "'iParo'")


# -- an initial value that is no value ------------------------------------------------------
FALLA = MOTOR.replace("WHEN", "iParo").replace("outputs: [oMotor]",
                                               "outputs: [oMotor]\nmemory:\n  sFalla: INIT")

TYPES = ("false or true (bool), an integer such as 0 (int), a real such as 0.0 (real) or a "
         "time such as 10s (time)")


@pytest.mark.parametrize("init", ["no", "off", "Yes"])
def test_initial_value_written_yes_no_on_off(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str],
                                             init: str) -> None:
    text = FALLA.replace("INIT", init)
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, init, f"expected an initial value for 'sFalla': {TYPES}, found the "
                              f"text '{init}' (yes, no, on and off are text in these files: "
                              "write false or true)")


def test_initial_value_that_is_a_word(tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    text = FALLA.replace("INIT", "falso")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "falso", f"expected an initial value for 'sFalla': {TYPES}, found "
                                 "the text 'falso'")


def test_initial_value_that_is_a_bad_time_keeps_the_time_message(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Near miss: a text starting with a digit is meant as a time."""
    text = FALLA.replace("INIT", "10sec")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "10sec", "bad time literal '10sec' for the initial value of 'sFalla': "
                                 "expected e.g. 10s, 250ms, 1m30s or T#10s")


def test_retain_written_yes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = FALLA.replace("INIT", "{init: false, retain: yes}")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "yes", "expected true or false for retain, found the text 'yes' (yes, "
                               "no, on and off are text in these files: write false or true)")


# -- a timer that is not declared -------------------------------------------------------------
TIMER = MOTOR.replace("WHEN", "timeX.End()").replace(
    "{actions: [oMotor]}", "\n    actions:\n      - P1 timeX.Ini(5s)\n      - oMotor")


def test_undeclared_timer(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert compile_error(tmp_path, capsys, TIMER) == line(
        tmp_path, TIMER, "timeX.Ini", "unknown timer 'timeX': declare it in the chart's list "
                                      "of timers (timers: [timeX])")


def test_misspelt_timer(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = TIMER.replace("outputs: [oMotor]", "outputs: [oMotor]\ntimers: [timeY]")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "timeX.Ini", "unknown timer 'timeX' (did you mean 'timeY'?): declare "
                                     "it in the chart's list of timers (timers: [timeY, "
                                     "timeX])")


def test_undeclared_function_block(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "tonArranque.Q")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "tonArranque", "unknown function block 'tonArranque': declare it in "
                                       "the chart's mapping of blocks (blocks: {tonArranque: "
                                       "TON})")


# -- the structure of steps and transitions ----------------------------------------------------
SHAPE = ("expected the steps as a mapping, one step per line without '- ' (Ini: {initial: "
         "true} then Run: {actions: [oX]}), found a list")


def test_steps_written_as_list_items(tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace(
        "  Ini: {initial: true}\n  Arranque:", "  - Ini: {initial: true}\n  - Arranque:")
    assert compile_error(tmp_path, capsys, text) == line(tmp_path, text, "- Ini", SHAPE)


def test_actions_under_indented(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace(
        "  Arranque: {actions: [oMotor]}", "  Arranque:\n  actions:\n    - oMotor")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "actions:", "expected a step, found 'actions', a key of a step, at "
                                    "the level of the steps: indent it under its step, two "
                                    "spaces further in than 'Arranque:' (or write Arranque: "
                                    "{actions: [...]})")


def test_actions_at_the_top_level(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace(
        "  Arranque: {actions: [oMotor]}\n", "  Arranque:\nactions: [oMotor]\n")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "actions:", "unknown key 'actions' in a grafcet file: 'actions' is a "
                                    "key of a step: indent it under its step in 'steps:' "
                                    "(steps: {Arranque: {actions: [...]}})")


def test_actions_as_the_step_itself(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A list straight under a step's name: the step's actions without 'actions:'."""
    text = MOTOR.replace("WHEN", "iParo").replace(
        "  Arranque: {actions: [oMotor]}", "  Arranque:\n    - oMotor")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "- oMotor", "expected the definition of step 'Arranque' (a mapping "
                                    "such as {initial: true, actions: [oX]}), found a list: "
                                    "put the step's actions under 'actions:'")


def test_transitions_written_as_a_mapping(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("  - {from: Ini, to: Arranque, when: iMarcha}\n"
                         "  - {from: Arranque, to: Ini, when: WHEN}\n",
                         "  T1: {from: Ini, to: Arranque, when: iMarcha}\n")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "T1:", "expected a list of transitions, one per line after '- ' "
                               "(- {from: Ini, to: Run, when: iMarcha}), found a mapping")


def test_transition_keys_inside_a_step(tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace(
        "{actions: [oMotor]}", "{actions: [oMotor], to: Ini}")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "to:", "unknown key 'to' in step 'Arranque': expected one of initial, "
                               "actions, min, max, macro, entry, exit, description, "
                               "renamed_from (a transition is written under 'transitions:' "
                               "as - {from: Arranque, to: B, when: CONDITION})")


# -- duplicate transition names ----------------------------------------------------------------
def test_duplicate_transition_names(tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace("  - {from:", "  - {name: T1, from:")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "T1", "expected each transition name once in the chart, found "
                              "'T1' again (first at line 8)", nth=1)


def test_duplicate_transition_names_inside_a_macro_step(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace(
        "  - {from: Arranque", "  - {name: T2, from: Arranque").replace(
        "  Arranque: {actions: [oMotor]}",
        "  Arranque:\n    macro:\n      steps:\n        E1: {entry: true, actions: [oMotor]}\n"
        "        S1: {exit: true}\n      transitions:\n"
        "        - {name: T2, from: E1, to: S1, when: iParo}")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "T2", "expected each transition name once in the chart, found "
                              "'T2' again (first at line 12)", nth=1)


def test_distinct_transition_names_load(tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Near miss: names given once each, and transitions without a name, compile."""
    text = MOTOR.replace("WHEN", "iParo").replace("  - {from: Ini", "  - {name: T1, from: Ini")
    text += "  - {name: T2, from: Ini, to: Arranque, when: iParo}\n"
    path = write(tmp_path, "chart.yaml", text)
    assert main(["compile", path]) == 0
    assert ": ok: Arranque1 compiled" in capsys.readouterr().err


# -- found writing the course exercises (seed 003: steps by number, ISaGRAF actions) ---------
def test_step_named_by_a_number(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace("  Ini: {initial: true}",
                                                  "  1: {initial: true}")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "1: {", "expected a name for a step (a letter or '_' first, then "
                                "letters, digits, '_'), found the number '1': write e.g. GS1")


def test_isagraf_action_block(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = MOTOR.replace("WHEN", "iParo").replace(
        "outputs: [oMotor]", "outputs: [oMotor]\nmemory: {sN: 0}").replace(
        "{actions: [oMotor]}", "\n    actions:\n      - |\n        ACTION(N):\n"
        "          sN := sN + 1;\n        END_ACTION;")
    assert compile_error(tmp_path, capsys, text) == line(
        tmp_path, text, "ACTION(N)", "expected an action as 'QUALIFIER statements' (e.g. 'N x "
                                     ":= x + 1' or 'P1 x := x + 1'), found an ACTION(...): ... "
                                     "END_ACTION block: write the qualifier first, without "
                                     "ACTION and END_ACTION")


def test_block_named_action_is_still_a_call(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Near miss: a function block that happens to be named Action is called as any other."""
    text = MOTOR.replace("WHEN", "Action.Q").replace(
        "outputs: [oMotor]", "outputs: [oMotor]\nblocks: {Action: TON}").replace(
        "{actions: [oMotor]}", "{actions: ['Action(IN := iParo, PT := 2s)']}")
    path = write(tmp_path, "chart.yaml", text)
    assert main(["compile", path]) == 0, capsys.readouterr().err


# -- YAML slips (issue 30 §2): PyYAML's words replaced by the file's and a fix -----------------
HEAD = MOTOR[:MOTOR.index("transitions:")] + "transitions:\n"
FIRST = "  - {from: Ini, to: Arranque, when: iMarcha}\n"
BLOCK = "  - from: Arranque\n    to: Ini\n    when: WHEN\n"
QUOTE = "quote a text that begins with"


@pytest.mark.parametrize("body, needle, message", [
    (FIRST + "\t- {from: Arranque, to: Ini, when: iParo}\n", "\t",
     "expected spaces, found a tab in the indentation of '- {from: Arranque, to: Ini, when: "
     "iParo}': YAML indents with spaces, never tabs"),
    (FIRST.replace("}", "}\t") + "  - {from: Arranque, to: Ini, when: iParo}\n", "\t",
     "expected a space, found a tab after '...om: Ini, to: Arranque, when: iMarcha}': YAML "
     "separates with spaces, never tabs"),
    (FIRST + "  - {from: Arranque, to: Ini, when: !iParo}\n", "!iParo",
     f"expected a value, found '!iParo', which YAML reads as a tag: {QUOTE} '!': \"!iParo\"; "
     "a negation is NOT iParo or iParo'"),
    (FIRST + BLOCK.replace("WHEN", "!iParo"), "!iParo",
     f"expected a value, found '!iParo', which YAML reads as a tag: {QUOTE} '!': \"!iParo\"; "
     "a negation is NOT iParo or iParo'"),
    (FIRST + "  - {from: Arranque, to: Ini, when: *iParo}\n", "*iParo",
     "expected a value, found '*iParo', which YAML reads as an undefined alias (a copy of the "
     f"value marked &iParo, and none is): {QUOTE} '*': \"*iParo\""),
    (FIRST + BLOCK.replace("WHEN", "*iParo"), "*iParo",
     "expected a value, found '*iParo', which YAML reads as an undefined alias (a copy of the "
     f"value marked &iParo, and none is): {QUOTE} '*': \"*iParo\""),
    (FIRST + "  - {from: Arranque, to: Ini, when: &iParo}\n", "&iParo",
     "expected a value after '&iParo', found nothing: YAML reads '&iParo' as an anchor (a "
     f"name for the value after it): {QUOTE} '&': \"&iParo\""),
    (FIRST + "  - {from: Arranque, to: Ini, when: @iParo}\n", "@iParo",
     "expected a value, found '@iParo': YAML reserves '@' at the start of a value: quote it: "
     "\"@iParo\""),
    (FIRST + BLOCK.replace("WHEN", "`iParo`"), "`iParo`",
     "expected a value, found '`iParo`': YAML reserves '`' at the start of a value: quote "
     "it: \"`iParo`\""),
    (FIRST + "  - {from: Arranque, to: Ini, when: %iParo}\n", "%iParo",
     "expected a value, found '%iParo': YAML reserves '%' at the start of a value: quote it: "
     "\"%iParo\""),
    (FIRST + BLOCK.replace("WHEN", "|iParo| > 0"), "|iParo|",
     "expected a block text ('|' alone at the end of the line, the text on the lines below), "
     "found '|iParo| > 0': quote a value that begins with '|': \"|iParo| > 0\""),
    (FIRST + BLOCK.replace("WHEN", "[iParo] AND iMarcha"), "AND",
     "expected the end of the value after '[iParo]', found 'AND iMarcha': a value that "
     "begins with '[' is a list and ends where it closes: quote the whole value: "
     "\"[iParo] AND iMarcha\""),
    (FIRST + BLOCK.replace("WHEN", "{iParo} OR iMarcha"), "OR",
     "expected the end of the value after '{iParo}', found 'OR iMarcha': a value that "
     "begins with '{' is a mapping and ends where it closes: quote the whole value: "
     "\"{iParo} OR iMarcha\""),
    (FIRST + "  - {from: Arranque, to: Ini, when: \"iParo\" AND iMarcha}\n", "AND",
     "expected the end of the value after '\"iParo\"', found 'AND iMarcha': a value that "
     "begins with '\"' is a quoted text and ends where it closes: quote the whole value: "
     "\"iParo AND iMarcha\""),
    ("  from: Ini\n  to: Arranque\n  when: iMarcha\n  - {from: Arranque, to: Ini, when: "
     "iParo}\n", "- {from: Arranque",
     "expected a key of the mapping that begins at line 8 ('from: Ini'), found a list item "
     "('- {from: Arranque, to: Ini, when: iParo}'): the items of a list each begin with '- ' "
     "at one indentation: write '- from: Ini'"),
    (FIRST + "  from: Arranque\n  to: Ini\n  when: iParo\n", "from: Arranque",
     "expected an item ('- ') of the list that begins at line 8, found a key ('from: "
     "Arranque'): begin it with '- ' ('- from: Arranque'), the keys that go with it indented "
     "under it"),
    (FIRST + BLOCK.replace("WHEN", "iParo").replace("    to:", "     to:"), "to: Ini",
     "expected the key 'to' at column 5, aligned with 'from' above it, found it at column 6, "
     "where YAML reads it as more of the value of 'from': align it"),
    (FIRST + BLOCK.replace("WHEN", "iParo").replace("    to:", "   to:"), "to: Ini",
     "expected an item ('- ') of the list that begins at line 8 (column 3) or a key aligned "
     "with 'from' above it (column 5), found 'to: Ini' at column 4: align it"),
], ids=["tab indenting", "tab after a value", "!x in a flow", "!x", "*x in a flow", "*x",
        "&x", "@x", "`x`", "%x", "|x|", "[x] and more", "{x} and more", "quoted and more",
        "a mapping before list items", "a mapping after list items", "a key further in",
        "a key further out"])
def test_a_yaml_slip_says_what_to_write(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                        body: str, needle: str, message: str) -> None:
    text = HEAD + body
    assert compile_error(tmp_path, capsys, text) == line(tmp_path, text, needle,
                                                         "YAML syntax: " + message)


@pytest.mark.parametrize("steps, needle, message", [
    ("  Ini: {initial: true, description: Pump P1: stopped}\n", ": stopped",
     "expected the end of the value of 'description' after 'Pump P1', found ': stopped': a "
     "text holding ': ' reads as a key and its value: quote the whole value: description: "
     "\"Pump P1: stopped\""),
    ("  Ini:\n    initial: true\n    description: Pump P1: stopped, waiting\n", ": stopped",
     "expected the end of the value of 'description' after 'Pump P1', found ': stopped, "
     "waiting': a text holding ': ' reads as a key and its value: quote the whole value: "
     "description: \"Pump P1: stopped, waiting\""),
], ids=["in a flow mapping", "in a block mapping"])
def test_a_text_holding_colon_space_says_to_quote_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], steps: str, needle: str,
        message: str) -> None:
    """An unquoted description holding ': ' (PyYAML: "expected ',' or '}', but got ':'")."""
    text = MOTOR.replace("WHEN", "iParo").replace("  Ini: {initial: true}\n", steps)
    assert compile_error(tmp_path, capsys, text) == line(tmp_path, text, needle,
                                                         "YAML syntax: " + message)
