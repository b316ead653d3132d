"""The scan's own memory across an edit: its keys are made of what it belongs to, so an edit
that inserts a transition or an edge before others carries each memory to its own owner."""

from __future__ import annotations

import textwrap

from runtime.change.diff import chart_plant
from runtime.change.plan import apply, prepare
from runtime.engine.plant import Plant
from runtime.language.grafcetfile import load_grafcet

MS = 1_000_000

BASE = """\
grafcet: Small
scan: {model}
inputs: [a, b]
outputs: [o]
steps:
  s0: {{initial: true}}
  s1: {{actions: [o]}}
  s2: {{}}
transitions:
{extra}  - {{from: s0, to: s1, when: "{cond}"}}
  - {{from: s1, to: s0, when: "b AND NOT a"}}
"""


def plant(tmp_path, name: str, text: str) -> Plant:
    path = tmp_path / f"{name}.yaml"
    path.write_text(textwrap.dedent(text))
    return Plant(chart_plant(load_grafcet(str(path))), sim=True, virtual=True)


def scan(p: Plant, k: int, **values: bool) -> None:
    for n, v in values.items():
        p.instances["Small"].set(n, v)
    p.cycle(k * 10 * MS)


def swap(old: Plant, new: Plant) -> Plant:
    prep = prepare(old, new.pdef)
    res = apply(old, prep)
    assert res.refusals == []
    return prep.plant


def test_a_pending_codesys_evolution_follows_its_transition(tmp_path):
    """CODESYS: the scan with ``a`` decides s0 -> s1 for the next scan; the edit inserts a
    transition before it. The evolution stays s0 -> s1's (sequence-numbered memory would
    hand it to the inserted transition, whose source is inactive: the chart would stay in
    s0)."""
    old = plant(tmp_path, "old", BASE.format(model="codesys", extra="", cond="a"))
    scan(old, 0)
    scan(old, 1, a=True)
    assert old.instances["Small"].active_steps() == ["s0"]  # decided, not yet taken
    new = plant(tmp_path, "new", BASE.format(
        model="codesys", cond="a", extra='  - {from: s2, to: s0, when: "1"}\n'))
    run = swap(old, new)
    scan(run, 2, a=False)
    assert run.instances["Small"].active_steps() == ["s1"]


def test_a_new_edge_sees_a_rise_in_the_swap_scan(tmp_path):
    """An edge the old chart had not remembers its input's value of the last scan: a rise
    of ``b`` in the very scan after the swap fires the new transition (an edge memory
    started at its power-up value would miss it)."""
    old = plant(tmp_path, "old", BASE.format(model="immediate", extra="", cond="a"))
    scan(old, 0)
    scan(old, 1, a=True, b=False)
    assert old.instances["Small"].active_steps() == ["s1"]
    new = plant(tmp_path, "new", BASE.format(
        model="immediate", cond="a", extra='  - {from: s1, to: s2, when: "RE b"}\n'))
    run = swap(old, new)
    scan(run, 2, b=True)
    assert run.instances["Small"].active_steps() == ["s2"]


MEMORY_EDGE = """\
grafcet: Small
inputs: [a, b]
outputs: [o]
memory: {k: false}
pre: ["k := a"]
steps:
  s0: {initial: true}
  s1: {actions: [o]}
  s2: {}
transitions:
EXTRA  - {from: s0, to: s1, when: "RE k"}
"""


def test_an_edge_keeps_its_memory_when_an_edge_is_inserted_before_it(tmp_path):
    """``RE k`` on a memory variable (no input to take its value from): ``k`` was 0 in the
    last scan of the old chart and rises in the swap scan, so the edge fires there. The
    edit inserts an edge on ``b`` in an earlier transition; ``RE k`` keeps its own memory
    (sequence-numbered memory would start it afresh and miss the rise)."""
    old = plant(tmp_path, "old", MEMORY_EDGE.replace("EXTRA", ""))
    scan(old, 0, a=False, b=False)
    scan(old, 1, a=False, b=False)
    new = plant(tmp_path, "new", MEMORY_EDGE.replace(
        "EXTRA", '  - {from: s2, to: s0, when: "FE b"}\n'))
    run = swap(old, new)
    scan(run, 2, a=True)
    assert run.instances["Small"].active_steps() == ["s1"]
