"""No text of a chart or plant file runs as code: every text a file may hold (descriptions,
ST comments in conditions, actions, pre and post equations, the I/O list) carrying line
breaks of every kind and a Python payload either loads and compiles to the very program the
same file compiles to without the payload (comments and descriptions never reach the code),
or is refused with one ``FILE:LINE:COL: error:`` line; and the payload never runs, in the
chart's own scan or in the plant's inlined cycle."""

from __future__ import annotations

import ast
import hashlib
import json
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.compiler.codegen import compile_grafcet
from runtime.engine.instance import Instance
from runtime.engine.plant import Plant
from runtime.errors import SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import load_plant

MS = 1_000_000

#: what may end or break a line for one reader or another, and Python's quotes and escape
SEPARATORS = ["\r", "\n", "\r\n", "\x0b", "\x0c", "\x1c", "\x1d", "\x1e", "\x85", "\u2028",
              "\u2029", '"""', "'''", "\\", "\x00"]

#: the chart's texts: D* descriptions, C* the insides of ST comments
CHART = """\
grafcet: Hostile
description: {D0}
inputs: [iA, {{iB: {{type: bool, description: {D1}}}}}, {{iN: int}}]
outputs: [oB, oC]
memory:
  sX: {{init: 0, description: {D2}}}
pre:
  - {P0}
steps:
  s1:
    initial: true
    description: {D3}
    actions: [{A0}, {A1}]
  s2: {{description: {D4}, actions: [oB]}}
transitions:
  - {{from: s1, to: s2, when: {W0}}}
  - {{from: s2, to: s1, when: {W1}}}
post:
  - {P1}
"""
#: the texts holding an ST comment, around the comment's inside ``{}``
AROUND = {"P0": "tQ := iA (* {} *)", "A0": "P1 sX := sX + 1 (* {} *)",
          "A1": "N oC if iB // {}", "W0": "iA (* {} *) AND NOT iB", "W1": "NOT iA // {}",
          "P1": "sX := sX (* {} *)"}
DESCRIPTIONS = ["D0", "D1", "D2", "D3", "D4"]
PLANT = """\
drivers:
  sim: {{type: sim}}
instances:
  t:
    grafcet: chart.yaml
    description: {D5}
    inputs:
      iA: {{from: sim.I0, description: {D6}}}
      iB: {{from: sim.I1, description: {D7}}}
      iN: {{from: sim.W0, unit: {D8}}}
    outputs:
      oB: {{from: sim.Q0, description: {D9}}}
      oC: sim.Q1
"""
PLANT_TEXTS = ["D5", "D6", "D7", "D9"]


def payload(marker: Path, sep: str, indent: int) -> str:
    """Python that writes ``marker`` if it ever runs, between two ``sep`` at ``indent``."""
    pad = " " * indent
    return f"{sep}{pad}open({str(marker)!r}, 'w').write('ran'){sep}{pad}#"


def quoted(text: str) -> str:
    """``text`` as a YAML double-quoted scalar (JSON's escapes are YAML's)."""
    return json.dumps(text)


def chart_file(texts: dict[str, str]) -> str:
    """The chart with ``texts`` (slot -> inside of the comment or description)."""
    values = {k: quoted(texts.get(k, "x")) for k in DESCRIPTIONS}
    values |= {k: quoted(a.format(texts.get(k, "x"))) for k, a in AROUND.items()}
    return CHART.format(**values)


def plant_file(texts: dict[str, str]) -> str:
    return PLANT.format(**{k: quoted(texts.get(k, "x")) for k in PLANT_TEXTS}, D8=quoted("m"))


def shape(source: str) -> str:
    """The syntax tree of a generated source with its strings blanked (what it does), as
    its hash."""
    tree = ast.parse(source)
    for n in ast.walk(tree):
        if isinstance(n, ast.Constant) and isinstance(n.value, str):
            n.value = ""
    return hashlib.sha256(ast.dump(tree, include_attributes=False).encode()).hexdigest()


def plant_shapes(plant: Plant) -> list[str]:
    return [shape(plant.source), *(shape(s) for s in plant._inliner.sources)]


_REFUSAL = re.compile(r"^\S+\.yaml:\d+:\d+: error: [^\n]+$")


def run(tmp: Path, texts: dict[str, str]) -> tuple[str, list[str]] | str:
    """Load, compile and run the chart and its plant holding ``texts``: the shapes of the
    chart's program and of the plant's cycle, or the one-line refusal."""
    chart = tmp / "chart.yaml"
    chart.write_text(chart_file(texts), encoding="utf-8")
    (tmp / "plant.yaml").write_text(plant_file(texts), encoding="utf-8")
    try:
        program = compile_grafcet(load_grafcet(str(chart)))
        plant = Plant(load_plant(str(tmp / "plant.yaml")), sim=True)
    except SourceError as e:
        assert _REFUSAL.match(str(e)), str(e)
        return str(e)
    inst = Instance("t", program)
    for k, a in enumerate([0, 0, 1, 1, 0, 0, 1, 0]):  # both transitions fire, both actions
        inst.set("iA", bool(a))
        inst.scan(k * 10 * MS, k * 10 * MS)
    plant.open()
    sim = plant.drivers["sim"]
    for k, a in enumerate([0, 0, 1, 1, 0, 0, 1, 0]):
        sim.inputs["I0"] = a
        plant.cycle(k * 10 * MS)
    plant.close()
    return shape(program.source), plant_shapes(plant)


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> tuple[str, list[str]]:
    """The shapes of the chart and plant with harmless texts."""
    out = run(tmp_path_factory.mktemp("clean"), {})
    assert not isinstance(out, str), out
    return out


ALL = [*DESCRIPTIONS, *AROUND, *PLANT_TEXTS]


@pytest.mark.parametrize("sep", SEPARATORS, ids=[repr(s) for s in SEPARATORS])
def test_every_text_holding_a_separator_and_a_payload_never_runs(
        tmp_path: Path, clean: tuple[str, list[str]], sep: str) -> None:
    """Each text alone (a refusal of one would hide the others), at every indentation a
    line of the generated code may have."""
    marker = tmp_path / "ran"
    for slot in ALL:
        for indent in range(0, 28, 4):
            out = run(tmp_path, {slot: payload(marker, sep, indent)})
            assert not marker.exists(), f"the payload in {slot} ran at indent {indent}"
            if not isinstance(out, str):  # the same program as without the payload
                assert out == clean, f"{slot} at indent {indent} changed the program"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow,
          HealthCheck.function_scoped_fixture])
@given(st.dictionaries(st.sampled_from(ALL), st.tuples(
    st.sampled_from(SEPARATORS), st.integers(0, 24), st.text(max_size=8)), min_size=1))
def test_any_mix_of_hostile_texts_never_runs(
        tmp_path: Path, clean: tuple[str, list[str]],
        texts: dict[str, tuple[str, int, str]]) -> None:
    marker = tmp_path / "ran"
    marker.unlink(missing_ok=True)
    hostile = {k: extra.replace("*)", "") + payload(marker, sep, indent)
               for k, (sep, indent, extra) in texts.items()}
    out = run(tmp_path, hostile)
    assert not marker.exists()
    if not isinstance(out, str):
        assert out == clean


def test_a_carriage_return_in_a_condition_comment_stays_in_its_comment(tmp_path: Path) -> None:
    """The attack as it was found: CRs in an ST comment of a transition condition, the
    payload indented as the scan's body is (it ran in the chart's scan before)."""
    marker = tmp_path / "ran"
    inside = f"\r{' ' * 16}open({str(marker)!r}, 'w').write('ran')\r{' ' * 16}#"
    chart = tmp_path / "chart.yaml"
    chart.write_text(chart_file({"W0": inside}), encoding="utf-8")
    program = compile_grafcet(load_grafcet(str(chart)))
    inst = Instance("t", program)
    for k, a in enumerate([0, 1, 1, 0]):
        inst.set("iA", bool(a))
        inst.scan(k * 10 * MS, k * 10 * MS)
    assert inst.active_steps() == ["s1"]  # s1 -> s2 -> s1: the condition was evaluated
    assert not marker.exists()
    line = next(x for x in program.source.split("\n") if "open(" in x)
    assert line.lstrip().startswith("# s1 -> s2 when iA (* \\r")


@pytest.mark.parametrize("words", ["m", "m slow", "a_s1 l_s1", "x_s1 v_sX m"])
def test_names_in_a_comment_do_not_change_the_program(
        tmp_path: Path, clean: tuple[str, list[str]], words: str) -> None:
    """A comment naming what the generated code names (``m``, ``slow``, a step's marks, a
    slot) is a comment only: found by the property test above, where an action's comment
    ``m`` followed by a carriage return added ``m`` to a ``nonlocal`` of the generated
    scan (the names it declares were read from its text, comments included)."""
    for sep in ("\r", " "):
        out = run(tmp_path, {"A0": words + sep + "x", "W0": words, "P1": words})
        assert out == clean, (words, sep)


@pytest.mark.parametrize("scan", ["immediate", "stable", "codesys"])
@pytest.mark.parametrize("words", ["m", "m slow", "a_s1 l_s1", "x_s1 v_sX m"])
def test_names_in_a_string_of_the_code_do_not_change_the_program(
        tmp_path: Path, scan: str, words: str) -> None:
    """A chart's text the generated code carries as a string (a stable chart's transition
    texts, in the error it raises when it does not settle) is a string only: its words
    named no mark to clear (a condition's comment ``a_s1`` kept the clear of step s1's
    entered mark in a stable chart's scan)."""
    def program(texts: dict[str, str]) -> str:
        chart = tmp_path / "chart.yaml"
        chart.write_text(chart_file(texts).replace(
            "grafcet: Hostile\n", f"grafcet: Hostile\nscan: {scan}\n"), encoding="utf-8")
        return shape(compile_grafcet(load_grafcet(str(chart))).source)

    assert program({"W0": words, "W1": words}) == program({}), words
