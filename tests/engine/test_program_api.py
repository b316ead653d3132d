"""The compiled Program's API: slot layout, accessors, the one step-time formula."""

from __future__ import annotations

import pytest

from runtime.compiler.program import SlotKind

CHART = """\
grafcet: Api
inputs: [go]
outputs: [o]
memory:
  n: 3
steps:
  s0: {initial: true}
  s1: {actions: [o]}
transitions:
  - {from: s0, to: s1, when: go}
"""


def test_slots_describe_the_layout(chart):  # type: ignore[no-untyped-def]
    prog = chart(CHART).inst.program
    assert [s.index for s in prog.slots] == list(range(len(prog.slots)))
    by = {(s.kind, s.name): s for s in prog.slots}
    assert by[(SlotKind.VARIABLE, "n")].index == prog.var_index("n")
    assert by[(SlotKind.STEP_X, "s1")].index == prog.x_index("s1")
    assert prog.index_of("s1.X") == prog.x_index("s1")
    assert prog.index_of("go") == prog.var_index("go")
    assert sum(s.kind is SlotKind.CLOCK for s in prog.slots) == 1
    with pytest.raises(KeyError):
        prog.var_index("s1.X")


def test_accessors_read_and_write_a_state_list(chart):  # type: ignore[no-untyped-def]
    c = chart(CHART)
    prog, m = c.inst.program, c.inst.m
    assert prog.read(m, "n") == 3
    prog.write(m, "n", 9)
    assert c["n"] == 9
    c.scan().scan(go=1).run(3)
    assert prog.step_active(m, "s1") and not prog.step_active(m, "s0")
    assert prog.step_time(m, "s1") == c.inst.get("s1.T") == 30_000_000
    assert prog.step_time_reader("s0")(m) == 10_000_000  # kept after deactivation


def test_a_state_getter_follows_scans_and_outside_writes(chart):  # type: ignore[no-untyped-def]
    c = chart(CHART)
    prog, m = c.inst.program, c.inst.m
    get = m.getter([prog.var_index("n"), prog.x_index("s0"), prog.x_index("s1")])
    assert get() == (3, True, False)
    c.scan().scan(go=1)
    assert get() == (3, False, True)  # the scan's own stores are seen
    prog.write(m, "n", 7)
    assert get() == (7, False, True)  # and a write between scans
    assert get() == tuple(m[i] for i in (prog.var_index("n"), prog.x_index("s0"),
                                         prog.x_index("s1")))
