"""semantics.md, "scan: codesys", and the cycle-by-cycle table of seed 004."""

from __future__ import annotations

SEED004 = """\
grafcet: Seed004
scan: codesys
inputs: [T1, T2, T3]
memory:
  Paso1AccionP1: false
  Paso1AccionN: false
  Paso1AccionP0: false
  Paso2AccionP1: false
  Paso2AccionN: false
  Paso2AccionP0: false
steps:
  Pasoinicial: {initial: true}
  Paso1:
    actions:
      - P1 Paso1AccionP1 := TRUE
      - N Paso1AccionN := TRUE
      - P0 Paso1AccionP0 := TRUE
  Paso2:
    actions:
      - P1 Paso2AccionP1 := TRUE
      - N Paso2AccionN := TRUE
      - P0 Paso2AccionP0 := TRUE
transitions:
  - {from: Pasoinicial, to: Paso1, when: T1}
  - {from: Paso1, to: Paso2, when: T2}
  - {from: Paso2, to: Pasoinicial, when: T3}
"""

VARS = ["Paso1AccionP1", "Paso1AccionN", "Paso1AccionP0", "Paso2AccionP1", "Paso2AccionN",
        "Paso2AccionP0", "T1", "T2", "T3"]


def row(c) -> str:  # type: ignore[no-untyped-def]
    """The seed's watch list, as its digits: 1 = TRUE."""
    return "".join(str(int(c[v])) for v in VARS)


def test_seed004_cycle_by_cycle(chart):
    c = chart(SEED004)
    # the watch list as the seed shows it, one table per scan ("Ciclo k")
    c.scan()
    assert row(c) == "000000000" and c.steps == ["Pasoinicial"]
    c.scan(T1=1)  # "Ciclo 1": T1 made true before scan 1
    assert row(c) == "000000100" and c.steps == ["Pasoinicial"]
    c.scan()  # "Ciclo 2": Paso1's P1 and N actions run
    assert row(c) == "110000100" and c.steps == ["Paso1"]
    c.set(Paso1AccionP1=0)  # the seed writes the latch back to FALSE ("Write Values")
    c.scan(T2=1)  # T2 true before scan 3: Paso1 still current
    assert row(c) == "010000110" and c.steps == ["Paso1"]
    c.scan()  # scan 4: Paso1's P0, Paso2's P1 and N
    assert row(c) == "011110110" and c.steps == ["Paso2"]
    c.scan(T1=0, T2=0, T3=1)
    assert row(c) == "011110001" and c.steps == ["Paso2"]
    c.scan()  # Paso2's P0; back in Pasoinicial
    assert row(c) == "011111001" and c.steps == ["Pasoinicial"]


def test_seed004_all_transitions_true_from_the_start_one_step_per_scan(chart):
    c = chart(SEED004)
    rows, steps = [], []
    for _ in range(5):
        c.scan(T1=1, T2=1, T3=1)
        rows.append(row(c))
        steps.append(c.steps)
    assert rows == ["000000111", "000000111", "110000111", "111110111", "111111111"]
    assert steps == [["Pasoinicial"], ["Pasoinicial"], ["Paso1"], ["Paso2"], ["Pasoinicial"]]


def test_codesys_step_time_counts_from_the_first_scan_it_is_current(chart):
    c = chart(SEED004)
    c.scan().scan(T1=1)  # 10 ms: T1 true
    c.scan(T1=0)  # 20 ms: Paso1 current
    assert c.t_ms("Paso1") == 0
    c.scan(T2=1)  # 30 ms
    assert c.t_ms("Paso1") == 10
    c.scan(T2=0)  # 40 ms: Paso1 no longer current: its .T freezes
    assert c.t_ms("Paso1") == 20 and not c["Paso1.X"]
    c.run(3)
    assert c.t_ms("Paso1") == 20


CS = """\
grafcet: Cs
scan: codesys
inputs: [go, leave]
outputs: [oCur, oP]
memory: {n: 0, p: 0, seq: 0}
steps:
  s0: {initial: true, actions: ["P0 seq := seq * 10 + 1"]}
  s1:
    actions: ["N n := n + 1", "P p := p + 1", oCur, "P oP", "N seq := seq * 10 + 3",
              "P1 seq := seq * 10 + 2"]
  s2: {}
transitions:
  - {from: s0, to: s1, when: go}
  - {from: s1, to: s2, when: leave}
"""


def test_codesys_order_p0_then_p1_then_the_other_actions(chart):
    c = chart(CS).scan().scan(go=1)
    c.scan(go=0)
    assert c["seq"] == 123  # s0's P0 (written first), s1's P1, then s1's N


def test_codesys_final_scan_n_statement_runs_once_more_after_the_step_is_left(chart):
    c = chart(CS).scan().scan(go=1)
    c.scan(go=0)  # s1 current: 1
    c.scan(leave=1)  # 2, leave decided
    assert c["n"] == 2
    c.scan(leave=0)  # s2 current: the final scan of s1's N action
    assert c["n"] == 3 and c.steps == ["s2"]
    c.scan()
    assert c["n"] == 3


def test_codesys_p_statement_runs_twice(chart):
    c = chart(CS).scan().scan(go=1)
    c.scan(go=0)
    assert c["p"] == 1
    c.scan(leave=1)
    assert c["p"] == 1
    c.scan(leave=0)
    assert c["p"] == 2
    c.run(2)
    assert c["p"] == 2


def test_codesys_bool_targets_in_the_scans_the_step_is_current(chart):
    c = chart(CS).scan().scan(go=1)
    got = []
    for values in [{"go": 0}, {"leave": 1}, {"leave": 0}, {}]:
        c.scan(**values)
        got.append((int(c["oCur"]), int(c["oP"])))
    assert got == [(1, 1), (1, 0), (0, 0), (0, 0)]  # the final scan gives Q = false


def test_codesys_pause_holds_a_pending_evolution_and_its_p1_until_the_end(chart):
    c = chart(CS).scan().scan(go=1)
    c.scan(go=0, SFCPause=1)
    assert c.steps == ["s0"] and c["seq"] == 0
    c.scan()
    assert c.steps == ["s0"]
    c.scan(SFCPause=0)
    assert c.steps == ["s1"] and c["seq"] == 123


def test_codesys_sfcinit_drops_a_pending_evolution(chart):
    c = chart(CS).scan().scan(go=1)
    c.scan(go=0, SFCInit=1)
    c.scan(SFCInit=0)
    c.scan()
    assert c.steps == ["s0"]


def test_codesys_tip_mode(chart):
    c = chart(CS).scan(SFCTipMode=1)
    c.scan(go=1).scan()
    assert c.steps == ["s0"]
    c.scan(SFCTip=1)  # the transition fires in this scan; s1 is current in the next
    assert c.steps == ["s0"]
    c.scan()
    assert c.steps == ["s1"]


def test_codesys_min_time(chart):
    c = chart("""\
    grafcet: CsMin
    scan: codesys
    steps:
      s0: {initial: true}
      s1: {min: 30ms}
      s2: {}
    transitions:
      - {from: s0, to: s1, when: "1"}
      - {from: s1, to: s2, when: "1"}
    """).scan().scan()
    c.scan()  # 20 ms: s1 current
    assert c.steps == ["s1"]
    c.run(3)  # 50 ms: .T = 30 reached in this scan, s2 current in the next
    assert c.steps == ["s1"]
    c.scan()
    assert c.steps == ["s2"]


def test_codesys_max_time(chart):
    c = chart("""\
    grafcet: CsMax
    scan: codesys
    steps:
      s0: {initial: true}
      s1: {max: 20ms}
    transitions:
      - {from: s0, to: s1, when: "1"}
    """).scan().scan()
    c.scan().scan().scan()  # s1 current at 20 ms; .T = 20 at 40 ms
    assert not c["SFCError"]
    c.scan()
    assert c["SFCError"] and c["SFCErrorStep"] == "s1"


LD = """\
grafcet: CsLD
scan: codesys
inputs: [go, leave]
memory: {nL: 0, nD: 0}
steps:
  s0: {initial: true}
  s1: {actions: ["L 20ms nL := nL + 1", "D 20ms nD := nD + 1"]}
  s2: {}
transitions:
  - {from: s0, to: s1, when: go}
  - {from: s1, to: s2, when: leave}
"""


def test_codesys_final_scan_of_l_and_d_only_if_they_ran_in_the_scan_before(chart):
    # s1 current at 20 ms, left (decided) at 30 ms, s2 current at 40 ms
    c = chart(LD).scan().scan(go=1).scan(go=0).scan(leave=1)
    assert (c["nL"], c["nD"]) == (2, 0)
    c.scan(leave=0)
    assert (c["nL"], c["nD"]) == (3, 0)  # L's final scan; D never ran: no final scan
    # s1 current for 40 ms: L stopped at .T = 20, D running when left
    c = chart(LD).scan().scan(go=1).scan(go=0).run(3)
    assert (c["nL"], c["nD"]) == (2, 2)
    c.scan(leave=1)
    c.scan(leave=0)
    assert (c["nL"], c["nD"]) == (2, 4)


def test_codesys_final_scans_precede_the_actions_of_current_steps(chart):
    c = chart("""\
    grafcet: CsFinal
    scan: codesys
    inputs: [go]
    memory: {seq: 0}
    steps:
      s0: {initial: true}
      s2: {actions: ["N seq := seq * 10 + 2"]}
      s1: {actions: ["N seq := seq * 10 + 1"]}
    transitions:
      - {from: s0, to: s1, when: "1"}
      - {from: s1, to: s2, when: go}
    """).scan().scan().scan(go=1)
    c.scan(seq=0)  # s2 current: s1's final scan, then s2's N, although s2 is written first
    assert c["seq"] == 12
