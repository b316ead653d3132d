"""semantics.md, "Edges, timers, memory" and the system values of "The cycle"."""

from __future__ import annotations

import pytest

from tests.engine.enginekit import MS, S

# -- edges -------------------------------------------------------------------------------
START = """\
grafcet: Start
inputs: [start, stop]
outputs: [oRun]
steps:
  sIdle: {initial: true}
  sRun: {actions: [oRun]}
transitions:
  - {from: sIdle, to: sRun, when: ↑start}
  - {from: sRun, to: sIdle, when: stop}
"""


@pytest.mark.parametrize("model", ["immediate", "codesys", "stable"])
def test_a_start_button_held_at_power_up_does_not_start(chart, model):
    c = chart(START.replace("Start\n", f"Start\nscan: {model}\n"))
    c.run(5, start=1)
    assert c.steps == ["sIdle"] and not c["oRun"]
    c.scan(start=0).scan(start=1).scan()
    assert c.steps == ["sRun"]


def test_no_edge_on_the_first_scan_in_pre_either(chart):
    c = chart("""\
    grafcet: E
    inputs: [a]
    memory: {nUp: 0, nDown: 0}
    pre:
      - nUp := nUp + ↑a
      - nDown := nDown + ↓a
    steps:
      s0: {initial: true}
    """)
    c.scan(a=1)
    assert c["nUp"] == 0 and c["nDown"] == 0
    c.scan(a=0)
    assert c["nDown"] == 1
    c.scan(a=1)
    assert c["nUp"] == 1


def test_a_falling_edge_needs_a_true_previous_scan(chart):
    c = chart("""\
    grafcet: F
    inputs: [a]
    memory: {n: 0}
    pre: ["n := n + ↓a"]
    steps:
      s0: {initial: true}
    """)
    c.run(3, a=0)
    assert c["n"] == 0


def test_an_edge_in_a_transition_is_sampled_while_its_step_is_inactive(chart):
    # b rises while s1 is inactive; when s1 becomes active b is still true: no edge
    c = chart("""\
    grafcet: Samp
    inputs: [go, b]
    steps:
      s0: {initial: true}
      s1: {}
      s2: {}
    transitions:
      - {from: s0, to: s1, when: go}
      - {from: s1, to: s2, when: ↑b}
    """).scan()
    c.scan(b=1)
    c.scan(go=1)
    c.scan(go=0)
    assert c.steps == ["s1"]
    c.scan(b=0).scan(b=1)
    assert c.steps == ["s2"]


def test_an_edge_in_an_action_is_sampled_while_its_step_is_inactive(chart):
    c = chart("""\
    grafcet: SampA
    inputs: [go, b]
    memory: {n: 0}
    steps:
      s0: {initial: true}
      s1: {actions: ["on ↑b do n := n + 1", "N n := n + 10·↑b"]}
    transitions:
      - {from: s0, to: s1, when: go}
    """).scan()
    c.scan(b=1)  # the edge happens while s1 is inactive
    c.scan(b=1, go=1)
    assert c["n"] == 0
    c.scan(b=0).scan(b=1)
    assert c["n"] == 11


def test_an_edge_in_an_untaken_if_branch_is_sampled_every_scan(chart):
    c = chart("""\
    grafcet: SampIf
    inputs: [a, en]
    memory: {n: 0}
    pre:
      - |
        IF en THEN
          n := n + ↑a;
        END_IF
    steps:
      s0: {initial: true}
    """).scan()
    c.scan(a=1)  # edge while en is false
    c.scan(en=1)
    assert c["n"] == 0
    c.scan(a=0).scan(a=1)
    assert c["n"] == 1


def test_edge_of_an_expression(chart):
    c = chart("""\
    grafcet: EE
    inputs: [a, b]
    memory: {n: 0}
    pre: ["n := n + ↑(a·b)"]
    steps:
      s0: {initial: true}
    """).scan()
    c.scan(a=1).scan(b=1).scan(a=0).scan(a=1)
    assert c["n"] == 2


# -- IEC function blocks ------------------------------------------------------------------
def block_chart(kind: str, call: str) -> str:
    return f"""\
grafcet: FB
inputs: [a, b, c]
blocks: {{fb: {kind}}}
pre: ["{call}"]
steps:
  s0: {{initial: true}}
"""


def test_ton(chart):
    c = chart(block_chart("TON", "fb(IN := a, PT := 30ms)"))
    q, et = [], []
    for a in [0, 1, 1, 1, 1, 1, 0, 1]:
        c.scan(a=a)
        q.append(_member(c, "fb", "Q"))
        et.append(_member(c, "fb", "ET") // MS)
    assert q == [0, 0, 0, 0, 1, 1, 0, 0]
    assert et == [0, 0, 10, 20, 30, 30, 0, 0]


def test_tof(chart):
    c = chart(block_chart("TOF", "fb(IN := a, PT := 20ms)"))
    q, et = [], []
    for a in [0, 1, 0, 0, 0, 0, 1, 0]:
        c.scan(a=a)
        q.append(_member(c, "fb", "Q"))
        et.append(_member(c, "fb", "ET") // MS)
    assert q == [0, 1, 1, 1, 0, 0, 1, 1]
    assert et == [0, 0, 0, 10, 20, 20, 0, 0]


def test_tp_is_not_retriggered_while_running(chart):
    c = chart(block_chart("TP", "fb(IN := a, PT := 30ms)"))
    q = []
    for a in [0, 1, 0, 1, 0, 0, 1, 1, 1, 1, 0]:
        c.scan(a=a)
        q.append(_member(c, "fb", "Q"))
    assert q == [0, 1, 1, 1, 0, 0, 1, 1, 1, 0, 0]


def test_ctu(chart):
    c = chart(block_chart("CTU", "fb(CU := a, R := b, PV := 2)"))
    cv, q = [], []
    for a, b in [(1, 0), (0, 0), (1, 0), (1, 0), (0, 0), (1, 0), (1, 1), (0, 0)]:
        c.scan(a=a, b=b)
        cv.append(_member(c, "fb", "CV"))
        q.append(_member(c, "fb", "Q"))
    # IEC: the edge memory starts false, so a CU true at the first call counts
    assert cv == [1, 1, 2, 2, 2, 3, 0, 0]
    assert q == [0, 0, 1, 1, 1, 1, 0, 0]


def test_ctd(chart):
    c = chart(block_chart("CTD", "fb(CD := a, LD := b, PV := 2)"))
    cv, q = [], []
    for a, b in [(0, 1), (1, 0), (0, 0), (1, 0), (0, 0), (1, 0)]:
        c.scan(a=a, b=b)
        cv.append(_member(c, "fb", "CV"))
        q.append(_member(c, "fb", "Q"))
    assert cv == [2, 1, 1, 0, 0, -1]
    assert q == [0, 0, 0, 1, 1, 1]


def test_ctud(chart):
    c = chart("""\
    grafcet: FB
    inputs: [u, d, r, ld]
    blocks: {fb: CTUD}
    pre: ["fb(CU := u, CD := d, R := r, LD := ld, PV := 2)"]
    steps:
      s0: {initial: true}
    """)
    cv, qu, qd = [], [], []
    for u, d, r, ld in [(0, 0, 0, 0), (1, 0, 0, 0), (0, 0, 0, 0), (1, 0, 0, 0), (0, 1, 0, 0),
                        (1, 0, 0, 0), (0, 0, 0, 1), (1, 1, 0, 0), (0, 0, 1, 1)]:
        c.scan(u=u, d=d, r=r, ld=ld)
        cv.append(_member(c, "fb", "CV"))
        qu.append(_member(c, "fb", "QU"))
        qd.append(_member(c, "fb", "QD"))
    # up and down edges in the same call cancel; R dominates LD
    assert cv == [0, 1, 1, 2, 1, 2, 2, 2, 0]
    assert qu == [0, 0, 0, 1, 0, 1, 1, 1, 0]
    assert qd == [1, 0, 0, 0, 0, 0, 0, 0, 1]


def test_r_trig_memory_starts_false(chart):
    c = chart(block_chart("R_TRIG", "fb(CLK := a)"))
    q = []
    for a in [1, 1, 0, 1]:
        c.scan(a=a)
        q.append(_member(c, "fb", "Q"))
    assert q == [1, 0, 0, 1]  # IEC: unlike ↑a, the block fires on a CLK true at first call


def test_f_trig_iec_form(chart):
    c = chart(block_chart("F_TRIG", "fb(CLK := a)"))
    q = []
    for a in [0, 0, 1, 0, 0]:
        c.scan(a=a)
        q.append(_member(c, "fb", "Q"))
    # IEC body Q := NOT CLK AND NOT M; M := NOT CLK with M starting false
    assert q == [1, 0, 0, 1, 0]


def test_sr_is_set_dominant_and_rs_reset_dominant(chart):
    c = chart("""\
    grafcet: Bi
    inputs: [s, r]
    blocks: {sr: SR, rs: RS}
    pre: ["sr(S1 := s, R := r)", "rs(S := s, R1 := r)"]
    steps:
      s0: {initial: true}
    """)
    got = []
    for s, r in [(1, 0), (0, 0), (1, 1), (0, 1), (0, 0)]:
        c.scan(s=s, r=r)
        got.append((_member(c, "sr", "Q1"), _member(c, "rs", "Q1")))
    assert got == [(1, 1), (1, 1), (1, 0), (0, 0), (0, 0)]


def test_blocks_are_updated_only_when_called(chart):
    c = chart("""\
    grafcet: Called
    inputs: [go, a]
    outputs: [o]
    blocks: {ton: TON}
    steps:
      s0: {initial: true}
      s1: {actions: ["N ton(IN := a, PT := 20ms)"]}
    transitions:
      - {from: s0, to: s1, when: go}
    post: ["o := ton.Q"]
    """)
    c.scan(a=1).scan(a=1).scan(a=1)
    assert _member(c, "ton", "ET") == 0
    c.scan(go=1)  # first call at 30 ms: IN rises now
    c.scan()
    assert not c["o"]
    c.scan()
    assert c["o"]


def _member(c, block: str, member: str):  # type: ignore[no-untyped-def]
    v = getattr(c.inst.m[c.inst.index[block]], member)
    return int(v) if isinstance(v, bool) else v


# -- seed timers, Set, memory -------------------------------------------------------------
def test_seed_timer_ini_end_reset_val(chart):
    c = chart("""\
    grafcet: Seed
    inputs: [ini, rst]
    timers: [timeX]
    memory: {mEnd: false, mVal: 0s}
    pre:
      - IF ini THEN timeX.Ini(30ms); END_IF
      - IF rst THEN timeX.Reset(); END_IF
      - mEnd := timeX.End()
      - mVal := timeX.Val()
    steps:
      s0: {initial: true}
    """)
    got = []
    for ini, rst in [(0, 0), (1, 0), (0, 0), (0, 0), (0, 0), (0, 0), (1, 0), (0, 0), (0, 1)]:
        c.scan(ini=ini, rst=rst)
        got.append((int(c["mEnd"]), c["mVal"] // MS))
    assert got == [(0, 0), (0, 0), (0, 10), (0, 20), (1, 30), (1, 30), (0, 0), (0, 10), (0, 0)]


def test_set_method_writes_only_when_the_condition_holds(chart):
    c = chart("""\
    grafcet: Set
    inputs: [a, b]
    memory: {sB: false, sN: 0}
    pre: ["sB.Set(1, a)", "sN.Set(sN + 5, b)"]
    steps:
      s0: {initial: true}
    """)
    c.scan(a=0)
    assert not c["sB"] and c["sN"] == 0
    c.scan(a=1, b=1)
    assert c["sB"] is True and c["sN"] == 5
    c.scan(a=0, b=0)
    assert c["sB"] and c["sN"] == 5


def test_set_method_converts_like_an_assignment(chart):
    c = chart("""\
    grafcet: SetConv
    inputs: [a, b]
    memory: {sN: 0, sR: 0.0}
    pre: ["sN.Set(a, b)", "sR.Set(sN + 1, b)"]
    steps:
      s0: {initial: true}
    """)
    c.scan(a=1, b=1)
    assert c["sN"] == 1 and type(c["sN"]) is int
    assert c["sR"] == 2.0 and type(c["sR"]) is float


def test_memory_and_temporaries_keep_their_value_between_scans(chart):
    c = chart("""\
    grafcet: Mem
    inputs: [a]
    memory: {n: 0}
    pre:
      - IF a THEN tLast := n; END_IF
      - n := n + 1
    steps:
      s0: {initial: true}
    """)
    c.scan(a=1).scan(a=0).scan(a=0)
    assert c["n"] == 3 and c["tLast"] == 0


# -- system values ---------------------------------------------------------------------------
@pytest.mark.parametrize("name, period_ms", [("Clock_10Hz", 100), ("Clock_5Hz", 200),
                                             ("Clock_2Hz", 500), ("Clock_1Hz", 1000),
                                             ("Clock_0_5Hz", 2000)])
def test_clock_bits_are_true_in_the_first_half_of_each_period_from_start(chart, name,
                                                                         period_ms):
    c = chart(f"""\
    grafcet: Clk
    outputs: [o]
    post: ["o := {name}"]
    steps:
      s0: {{initial: true}}
    """)
    half = period_ms / 2
    for t, want in [(0, 1), (half - 1, 1), (half, 0), (period_ms - 1, 0), (period_ms, 1),
                    (5 * period_ms + half - 0.001, 1), (5 * period_ms + half, 0)]:
        c.scan_at(t)
        assert c["o"] == bool(want), (t, want)


def test_clock_bits_follow_up_not_the_monotonic_clock(chart):
    c = chart("""\
    grafcet: Clk
    outputs: [o]
    post: ["o := Clock_1Hz"]
    steps:
      s0: {initial: true}
    """)
    c.inst.scan(7 * S + 700 * MS, 0)  # now in the second half of a second, up = 0
    assert c["o"]
    c.inst.scan(8 * S + 200 * MS, 500 * MS)
    assert not c["o"]


def test_first_scan_is_true_in_the_first_scan_only_in_pre_and_post(chart):
    c = chart("""\
    grafcet: First
    outputs: [oPre, oPost]
    pre: ["tF := FirstScan"]
    post: ["oPre := tF", "oPost := FirstScan"]
    steps:
      s0: {initial: true}
    """)
    c.scan()
    assert c["oPre"] and c["oPost"]
    c.scan()
    assert not c["oPre"] and not c["oPost"]
    c.inst.restart()
    c.scan()
    assert c["oPre"] and c["oPost"]


def test_an_edge_is_sampled_at_the_start_of_the_top_level_statement_that_contains_it(chart):
    # choice (docs/semantics.md): an earlier pre statement's write is seen in the same scan,
    # a later one in the next scan
    c = chart("""\
    grafcet: Phase
    inputs: [a]
    memory: {nEarly: 0, nLate: 0}
    pre:
      - tA := a
      - nEarly := nEarly + ↑tA
      - nLate := nLate + ↑tB
      - tB := a
    steps:
      s0: {initial: true}
    """).scan()
    c.scan(a=1)
    assert (c["nEarly"], c["nLate"]) == (1, 0)
    c.scan()
    assert (c["nEarly"], c["nLate"]) == (1, 1)


def test_an_edge_in_an_action_is_sampled_before_the_bool_targets_take_their_value(chart):
    c = chart("""\
    grafcet: PhaseA
    inputs: [go]
    outputs: [o]
    memory: {n: 0}
    steps:
      s0: {initial: true, actions: ["on ↑o do n := n + 1"]}
      s1: {actions: [o]}
    transitions:
      - {from: [], to: s1, when: go}
    """).scan()
    c.scan(go=1)
    assert c["o"] and c["n"] == 0
    c.scan(go=0)
    assert c["n"] == 1
