"""Defects found by the engine tests, kept as regression tests.

``on`` is not a reserved word: it starts an ``on EVENT do`` action only when an event
expression follows it, so an output named ``On``/``oN``/``ON`` can be an N action, a
conditional N action, or assigned in a statement action; and YAML reads ``On`` as a name
(YAML 1.2 booleans), not as ``True``.
"""

from __future__ import annotations

import pytest

from runtime.errors import SourceError


@pytest.mark.parametrize("name", ["oN", "On", "ON", "on"])
def test_a_bare_output_named_like_the_on_keyword_is_an_n_action(chart, name):
    c = chart(f"""\
    grafcet: OnName
    inputs: [go]
    outputs: [{name}]
    steps:
      s0: {{initial: true}}
      s1: {{actions: [{name}]}}
    transitions:
      - {{from: s0, to: s1, when: go}}
    """).scan()
    assert not c[name]
    c.scan(go=1)
    assert c[name] and c.steps == ["s1"]


def test_an_output_named_on_in_conditional_and_statement_actions(chart):
    c = chart("""\
    grafcet: OnName
    inputs: [go, cond]
    outputs: [oN, On]
    memory: {n: 0}
    steps:
      s0: {initial: true, actions: ["On := go", "on ↑go do n := n + 1"]}
      s1: {actions: ["oN if cond"]}
    transitions:
      - {from: s0, to: s1, when: go AND cond}
    """).scan()
    c.scan(go=1)
    assert c["On"] and c["n"] == 1 and c.steps == ["s0"]
    c.scan(go=1, cond=1)
    assert c.steps == ["s1"] and c["oN"]
    c.scan(go=1, cond=0)
    assert not c["oN"]


def test_on_without_do_is_still_reported_as_an_event_action(chart):
    with pytest.raises(SourceError, match=r"expected 'do' after the event of an 'on EVENT "
                                          r"do' action, found 'n'"):
        chart("""\
        grafcet: OnName
        inputs: [go]
        memory: {n: 0}
        steps:
          s0: {initial: true, actions: ["on ↑go n := 1"]}
        """)
