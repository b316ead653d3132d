"""Bugs found by the engine tests in files owned by others (parser.py): strict xfails,
to be turned into plain tests when fixed."""

from __future__ import annotations

import pytest


@pytest.mark.xfail(strict=True, reason="parser.parse_action takes any action starting with "
                   "the word 'on' (case-insensitive) for 'on EVENT do', so a bare output "
                   "named oN / On cannot be an N action: 'expected an operand ... found end "
                   "of text'")
def test_a_bare_output_named_like_the_on_keyword_is_an_n_action(chart):
    c = chart("""\
    grafcet: OnName
    inputs: [go]
    outputs: [oN]
    steps:
      s0: {initial: true}
      s1: {actions: [oN]}
    transitions:
      - {from: s0, to: s1, when: go}
    """).scan()
    c.scan(go=1)
    assert c["oN"]
