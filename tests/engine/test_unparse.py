"""runtime/language/unparse.py: canonical text of expressions, text of a transition."""

from __future__ import annotations

from runtime.errors import Loc
from runtime.language.parser import parse_expression
from runtime.language.unparse import unparse


def text(src: str) -> str:
    return unparse(parse_expression(src, lambda off: Loc("t", 1, off + 1)))


def test_equal_expressions_have_equal_texts() -> None:
    assert text("a·b' + ↑c") == text("(a·NOT b) + RE c")  # untyped: · and + as parsed
    assert text("n >= 1000") == "(n >= 1000)"
    assert text("s1.T >= 5s") == "(s1.T >= 5s)"


def test_transition_text(chart) -> None:  # type: ignore[no-untyped-def]
    from runtime.language.unparse import transition_text
    c = chart("""\
        grafcet: Tt
        inputs: [go]
        steps:
          s0: {initial: true}
          s1: {}
        transitions:
          - {from: s0, to: s1, when: go}
        """)
    assert transition_text(c.inst.grafcet.transitions[0]) == "s0 -> s1 when go"
