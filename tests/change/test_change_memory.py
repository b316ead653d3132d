"""The scan's own memory across an edit: its keys are made of what it belongs to, so an edit
that inserts a transition or an edge before others carries each memory to its own owner."""

from __future__ import annotations

import textwrap

from runtime.change.diff import chart_plant
from runtime.change.plan import apply, prepare
from runtime.engine.plant import Plant
from runtime.language.grafcetfile import load_grafcet
from tests.change.changekit import state

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


BLOCKS = """\
grafcet: Small
inputs: [a, b]
outputs: [o]
timers: [timeX]
blocks: {ton1: TON, cnt: CTU}
pre:
  - ton1(IN := s1.X, PT := 100ms)
  - cnt(CU := a, R := FALSE, PV := 3)
steps:
  s0: {initial: true, actions: ["P1 timeX.Ini(70ms)"]}
  s1: {actions: [o]}
  s2: {}
  s3: {}
transitions:
  - {from: s0, to: s1, when: "timeX.End()"}
  - {from: s1, to: s2, when: ton1.Q}
  - {from: s2, to: s3, when: cnt.Q}
EXTRA"""


def trail(p: Plant, ks: range, a_at: set[int]) -> list[tuple[int, list[str]]]:
    out = []
    for k in ks:
        scan(p, k, a=k in a_at, b=False)
        out.append((k, p.instances["Small"].active_steps()))
    return out


def test_timers_and_counters_go_on_across_the_swap(tmp_path):
    """A seed timer and a TON running, a CTU counting: after the swap each ends in the very
    scan it would have ended in without the change, and the old plant's blocks are not
    shared with the new one."""
    pulses = {3, 5, 12, 14, 16}
    ref = plant(tmp_path, "ref", BLOCKS.replace("EXTRA", ""))
    want = trail(ref, range(0, 30), pulses)
    for k_swap in (4, 9, 13):
        old = plant(tmp_path, "old", BLOCKS.replace("EXTRA", ""))
        got = trail(old, range(0, k_swap), pulses)
        new = plant(tmp_path, "new", BLOCKS.replace("EXTRA", "  - {from: s3, to: s0, when: b}\n"))
        run = swap(old, new)
        before = state(old)
        got += trail(run, range(k_swap, 30), pulses)
        assert got == want, k_swap
        assert state(old) == before


def test_a_block_of_another_kind_starts_afresh(tmp_path):
    old = plant(tmp_path, "old", BLOCKS.replace("EXTRA", ""))
    trail(old, range(0, 12), {3, 5})
    new = plant(tmp_path, "new", BLOCKS.replace("EXTRA", "").replace("cnt: CTU", "cnt: CTD")
                .replace("cnt(CU := a, R := FALSE, PV := 3)", "cnt(CD := a, LD := FALSE, PV := 3)"))
    prep = prepare(old, new.pdef)
    res = apply(old, prep)
    assert "Small: block cnt starts from its initial state (was CTU)" in res.lines
    inst = prep.plant.instances["Small"]
    assert type(inst.m[inst.index["cnt"]]).__name__ == "CTD"


def test_the_memory_of_a_renamed_step_follows_it(tmp_path):
    """CODESYS: s0 -> S1 decided; the edit renames S1 to S9 (``renamed_from: S1``) and the
    stored memory M to N: the pending evolution, the edge of the transition leaving it and
    the S action's memory (of M, renamed N) follow the new names."""
    text = """\
        grafcet: Small
        scan: codesys
        inputs: [a, b]
        outputs: [o]
        memory: {M: false}
        steps:
          s0: {initial: true, actions: ["S M"]}
          S1: {actions: [o]}
          s2: {actions: ["R M"]}
        transitions:
          - {from: s0, to: S1, when: a}
          - {from: S1, to: s2, when: "RE b"}
        """
    old = plant(tmp_path, "old", text)
    scan(old, 0, b=True)
    scan(old, 1, a=True, b=True)
    assert old.instances["Small"].get("M") is True
    new_text = (text.replace("to: S1", "to: S9").replace("from: S1", "from: S9")
                .replace("S1: {actions: [o]}", "S9: {actions: [o], renamed_from: S1}")
                .replace("memory: {M: false}", "memory: {N: {init: false, renamed_from: M}}")
                .replace('"S M"', '"S N"').replace('"R M"', '"R N"'))
    new = plant(tmp_path, "new", new_text)
    prep = prepare(old, new.pdef)
    res = apply(old, prep)
    assert res.refusals == []
    run = prep.plant
    scan(run, 2, a=False, b=True)  # the pending s0 -> S9 is taken; b held: no edge
    inst = run.instances["Small"]
    assert inst.active_steps() == ["S9"]
    assert inst.get("N") is True  # stored: S in s0 left, still set
    scan(run, 3, b=True)
    assert inst.active_steps() == ["S9"]  # RE b: b was already 1 (its memory followed)


def test_an_l_action_given_to_an_active_step_counts_from_its_activation(tmp_path):
    """The edit gives the running step s1 its first L action: the new program keeps the
    clock its L, D and DS delays count from (``ta_``), which the old one did not have; it
    starts from the step's activation, not from the swap nor from the chart's start."""
    old = plant(tmp_path, "old", BASE.format(model="immediate", extra="", cond="a"))
    for k in range(3):
        scan(old, k, a=k == 1)  # s1 activated at 10 ms
    new = plant(tmp_path, "new", BASE.format(model="immediate", extra="", cond="a")
                .replace("s1: {actions: [o]}", 's1: {actions: ["L 50ms o"]}'))
    run = swap(old, new)
    seen = []
    for k in range(3, 8):
        scan(run, k)
        seen.append(run.instances["Small"].get("o"))
    assert seen == [True, True, True, False, False]  # 30, 40, 50 ms on; 60 ms: 50 ms since
