"""semantics.md, "One instance scan": the rules of evolution, one test per rule.

Every chart runs on a virtual clock (conftest.Chart): scan k at k·10 ms unless told.
"""

from __future__ import annotations

from pathlib import Path

import pytest

MODELS = ["immediate", "codesys", "stable"]

CHAIN = """\
grafcet: Chain
scan: {model}
inputs: [a, b]
outputs: [o0, o1, o2]
memory: {{n0: 0, n1: 0}}
steps:
  s0: {{initial: true, actions: [o0, "P1 n0 := n0 + 1"]}}
  s1: {{actions: [o1, "P1 n1 := n1 + 1"]}}
  s2: {{actions: [o2]}}
transitions:
  - {{from: s0, to: s1, when: a}}
  - {{from: s1, to: s2, when: b}}
  - {{from: s2, to: s0, when: "0"}}
"""


# -- scan models ------------------------------------------------------------------------
def test_immediate_the_chart_evolves_on_this_scans_inputs_and_outputs_show_it(chart):
    c = chart(CHAIN.format(model="immediate")).scan()
    c.scan(a=1)
    assert c.steps == ["s1"] and c["o1"] and not c["o0"] and c["n1"] == 1


def test_codesys_a_true_transition_shows_in_the_next_scan(chart):
    c = chart(CHAIN.format(model="codesys")).scan()
    c.scan(a=1)
    assert c.steps == ["s0"] and c["o0"] and not c["o1"] and c["n1"] == 0
    c.scan(a=0)
    assert c.steps == ["s1"] and c["o1"] and not c["o0"] and c["n1"] == 1


def test_stable_evolution_repeats_within_the_scan_until_stable(chart):
    c = chart(CHAIN.format(model="stable")).scan()
    c.scan(a=1, b=1)
    assert c.steps == ["s2"] and c["o2"] and not c["o1"] and c["n1"] == 1


def test_an_unknown_scan_model_is_rejected(chart):
    from runtime.errors import SourceError
    with pytest.raises(SourceError, match="unknown scan model"):
        chart(CHAIN.format(model="fast"))


# -- cycle 0 --------------------------------------------------------------------------
@pytest.mark.parametrize("model", MODELS)
def test_cycle_0_activates_the_initial_steps_and_fires_no_transition(chart, model):
    c = chart(CHAIN.format(model=model))
    assert c["s0.X"]  # before the first scan the instance shows its initial situation
    c.scan(a=1, b=1)
    assert c.steps == ["s0"] and c["o0"] and c["n0"] == 1  # P1 of the initial step ran
    c.scan()
    expected = {"immediate": ["s1"], "codesys": ["s0"], "stable": ["s2"]}[model]
    assert c.steps == expected
    assert c["n0"] == 1  # no second activation


@pytest.mark.parametrize("model", MODELS)
def test_cycle_0_runs_p_actions_of_initial_steps(chart, model):
    c = chart(f"""\
    grafcet: P0
    scan: {model}
    outputs: [o]
    memory: {{n: 0}}
    steps:
      s0: {{initial: true, actions: ["P o", "P n := n + 1"]}}
    """)
    c.scan()
    assert c["o"] and c["n"] == 1
    c.scan()
    assert not c["o"] and c["n"] == 1  # (the second run under codesys is on leaving)


@pytest.mark.parametrize("model", MODELS)
def test_cycle_0_pre_reads_the_initial_steps_as_active(chart, model):
    """Cycle 0's evolution is the initial steps' activation, yet the situation before it is
    already the initial one: pre equations of cycle 0 read s0.X TRUE (and s0.T 0), as IEC
    and matiec have the initial steps active from the start (docs/semantics.md)."""
    c = chart(f"""\
    grafcet: Pre0
    scan: {model}
    outputs: [o]
    memory: {{pX: false, pY: true, pT: false}}
    pre: ["pX := s0.X", "pY := s1.X", "pT := s0.T < 1ms"]
    steps:
      s0: {{initial: true}}
      s1: {{actions: [o]}}
    transitions:
      - {{from: s0, to: s1, when: "1"}}
    """)
    c.scan()
    assert (c["pX"], c["pY"], c["pT"]) == (True, False, True)


# -- one evolution per scan, priorities, divergences ------------------------------------
def test_immediate_at_most_one_evolution_per_scan(chart):
    c = chart(CHAIN.format(model="immediate")).scan()
    c.scan(a=1, b=1)
    assert c.steps == ["s1"]  # s1 activated now is not left before the next scan
    c.scan()
    assert c.steps == ["s2"]


OR_DIV = """\
grafcet: OrDiv
inputs: [a, b]
steps:
  s0: {initial: true}
  s1: {}
  s2: {}
  s3: {}
transitions:
  - {from: s0, to: s2, when: b}
  - {from: s0, to: s1, when: a}
  - {from: s0, to: s3, when: a·b}
  - {from: [s1, s2, s3], to: s0, when: "0"}
"""


@pytest.mark.parametrize("inputs, target", [({"a": 1, "b": 1}, "s2"), ({"a": 1}, "s1"),
                                            ({"b": 1}, "s2")])
def test_or_divergence_the_first_true_transition_in_file_order_wins(chart, inputs, target):
    c = chart(OR_DIV).scan()
    c.scan(**inputs)
    assert c.steps == [target]


def test_or_divergence_priority_follows_file_position_of_macro_transitions(chart):
    # transitions inside an expansion count where they are written
    c = chart("""\
    grafcet: Prio
    inputs: [a]
    steps:
      s0: {initial: true}
      m:
        macro:
          steps:
            e: {entry: true}
            x: {exit: true}
            y: {}
          transitions:
            - {from: e, to: y, when: a}
            - {from: e, to: x, when: a}
      s9: {}
    transitions:
      - {from: s0, to: m, when: "1"}
      - {from: m, to: s9, when: "0"}
    """).scan().scan()
    assert c.steps == ["e"]
    c.scan(a=1)
    assert c.steps == ["y"]


AND_DIV = """\
grafcet: AndDiv
inputs: [go, a, b, c]
outputs: [oJoin]
steps:
  s0: {initial: true}
  a1: {}
  a2: {}
  b1: {}
  j: {actions: [oJoin]}
transitions:
  - {from: s0, to: [a1, b1], when: go}
  - {from: a1, to: a2, when: a}
  - {from: [a2, b1], to: j, when: c}
  - {from: j, to: s0, when: "0"}
"""


def test_and_divergence_activates_every_target(chart):
    c = chart(AND_DIV).scan()
    c.scan(go=1)
    assert c.steps == ["a1", "b1"]


def test_and_convergence_fires_only_when_every_source_step_is_active(chart):
    c = chart(AND_DIV).scan()
    c.scan(go=1)
    c.scan(c=1)  # a2 is not active yet
    assert c.steps == ["a1", "b1"] and not c["oJoin"]
    c.scan(a=1, c=0)
    assert c.steps == ["a2", "b1"]
    c.scan(a=0, c=1)
    assert c.steps == ["j"] and c["oJoin"]


def test_a_step_taken_by_an_earlier_transition_is_not_taken_again(chart):
    # s1 is shared: t0 (s1 -> s2) comes first, so t1 ([s1, s3] -> s4) does not fire even
    # though all its source steps are active and its condition is true
    c = chart("""\
    grafcet: Taken
    inputs: [go]
    steps:
      s0: {initial: true}
      s1: {}
      s3: {}
      s2: {}
      s4: {}
    transitions:
      - {from: s0, to: [s1, s3], when: go}
      - {from: s1, to: s2, when: "1"}
      - {from: [s1, s3], to: s4, when: "1"}
    """).scan()
    c.scan(go=1)
    c.scan()
    assert c.steps == ["s3", "s2"]


# -- rule 5 ----------------------------------------------------------------------------
RULE5 = """\
grafcet: Rule5
inputs: [a]
outputs: [oP, oL]
memory: {n1: 0, n0: 0}
steps:
  s0: {initial: true}
  s1: {actions: ["P oP", "P1 n1 := n1 + 1", "P0 n0 := n0 + 1", "L 50ms oL"]}
transitions:
  - {from: s0, to: s1, when: "1"}
  - {from: s1, to: s1, when: a}
"""


def test_rule5_a_step_deactivated_and_activated_stays_active_and_restarts_its_time(chart):
    c = chart(RULE5).scan()
    c.scan()  # s1 activated at 10 ms
    c.run(3)
    assert c.t_ms("s1") == 30
    c.scan(a=1)  # 50 ms: s1 -> s1
    assert c.steps == ["s1"] and c["s1.X"] and c.t_ms("s1") == 0
    assert not c["oP"] and c["n1"] == 1 and c["n0"] == 0  # not activated (nor left) again
    assert c["oL"]  # 40 ms of the L's 50 since s1 became active
    c.scan(a=0)
    assert c.t_ms("s1") == 10
    assert not c["oL"]  # 50 ms since s1 became active: the L ended, .T's restart aside


RULE5_TIMED = """\
grafcet: Rule5Timed
inputs: [a]
outputs: [oL, oD, oDS]
memory: {nL: 0, nD: 0}
steps:
  s0: {initial: true}
  s1:
    actions: ["L 50ms oL", "D 50ms oD", "DS 50ms oDS", "L 50ms nL := nL + 1",
              "D 50ms nD := nD + 1"]
transitions:
  - {from: s0, to: s1, when: "1"}
  - {from: s1, to: s1, when: RE a}
"""


@pytest.mark.parametrize("scan", ["immediate", "stable"])
def test_rule5_leaves_the_l_d_and_ds_delays_running(chart, scan):
    """IEC 61131-3's ACTION_CONTROL times L, D and DS on the qualifier's input, the step's
    X, which stays TRUE when rule 5 leaves and re-enters the step in one evolution: the
    delays go on from the activation (docs/semantics.md), only .T restarts."""
    c = chart(RULE5_TIMED.replace("grafcet: Rule5Timed", f"grafcet: Rule5Timed\nscan: {scan}"))
    c.scan().scan()  # s1 activated at 10 ms
    c.run(3)  # 40 ms
    c.scan(a=1)  # 50 ms: s1 -> s1, .T restarts
    assert c.t_ms("s1") == 0 and c["oL"] and not c["oD"] and not c["oDS"]
    c.scan(a=0)  # 60 ms: 50 ms since the activation
    assert c.t_ms("s1") == 10
    assert (c["oL"], c["oD"], c["oDS"]) == (False, True, True)
    assert (c["nL"], c["nD"]) == (5, 1)  # L ran at 10..50 ms, D from 60 ms


def test_rule5_under_codesys_leaves_the_delays_running(chart):
    c = chart(RULE5_TIMED.replace("grafcet: Rule5Timed", "grafcet: Rule5Timed\nscan: codesys"))
    c.scan().scan()  # s0 current; s1 decided at 10 ms, current at 20 ms
    c.run(3)  # 50 ms
    c.scan(a=1)  # 60 ms: s1 -> s1 decided, current at 70 ms
    c.scan(a=0)  # 70 ms: .T restarts
    assert c.t_ms("s1") == 0 and c["oL"] and not c["oD"]
    c.scan()  # 80 ms: 60 ms since s1 became current at 20 ms
    assert (c["oL"], c["oD"], c["oDS"]) == (False, True, True)


def test_rule5_with_two_transitions_of_an_and_sequence(chart):
    c = chart("""\
    grafcet: Swap
    inputs: [a]
    steps:
      s0: {initial: true}
      s1: {}
      s2: {}
    transitions:
      - {from: s0, to: [s1, s2], when: "1"}
      - {from: s1, to: s2, when: a}
      - {from: s2, to: s1, when: a}
    """).scan().scan().scan()
    assert c.t_ms("s1") == 10 and c.t_ms("s2") == 10
    c.scan(a=1)
    assert c.steps == ["s1", "s2"] and c.t_ms("s1") == 0 and c.t_ms("s2") == 0


def test_activating_an_already_active_step_changes_nothing(chart):
    # choice (docs/semantics.md): the step stays active, its .T does not restart, no P1
    c = chart("""\
    grafcet: Twice
    inputs: [a]
    memory: {n: 0}
    steps:
      s0: {initial: true}
      s1: {actions: ["P1 n := n + 1"]}
      s2: {}
    transitions:
      - {from: s0, to: [s1, s2], when: "1"}
      - {from: s2, to: s1, when: a}
    """).scan().scan().run(2)
    assert c.t_ms("s1") == 20 and c["n"] == 1
    c.scan(a=1)
    assert c.steps == ["s1"] and c.t_ms("s1") == 30 and c["n"] == 1


# -- source and sink transitions ----------------------------------------------------------
SRC_SINK = """\
grafcet: SrcSink
inputs: [alarm, ack]
outputs: [oAlarm]
steps:
  s0: {initial: true}
  sAl: {actions: [oAlarm]}
transitions:
  - {from: [], to: sAl, when: ↑alarm}
  - {from: sAl, to: [], when: ack}
"""


def test_source_transition_is_always_enabled(chart):
    c = chart(SRC_SINK).scan()
    c.scan(alarm=1)
    assert c.steps == ["s0", "sAl"] and c["oAlarm"]


def test_source_transition_does_not_fire_in_cycle_0(chart):
    c = chart(SRC_SINK.replace("↑alarm", "alarm"))
    c.scan(alarm=1)
    assert c.steps == ["s0"]
    c.scan()
    assert c.steps == ["s0", "sAl"]


def test_sink_transition_deactivates_and_activates_nothing(chart):
    c = chart(SRC_SINK).scan()
    c.scan(alarm=1)
    c.scan(alarm=0, ack=1)
    assert c.steps == ["s0"] and not c["oAlarm"] and not c["sAl.X"]


# -- macro-steps -------------------------------------------------------------------------
MACRO = """\
grafcet: Macro
inputs: [go, a, b, out, back]
outputs: [oA, oB]
steps:
  s0: {initial: true}
  m:
    macro:
      steps:
        eA: {entry: true, actions: [oA]}
        inner:
          macro:
            steps:
              n1: {entry: true, actions: [oB]}
              n2: {exit: true}
            transitions:
              - {from: n1, to: n2, when: b}
        x: {exit: true}
      transitions:
        - {from: eA, to: inner, when: a}
        - {from: inner, to: x, when: "1"}
  s9: {}
transitions:
  - {from: s0, to: m, when: go}
  - {from: m, to: s9, when: out}
  - {from: m, to: m, when: back}
"""


def test_macro_step_activation_activates_its_entry_step_in_the_same_evolution(chart):
    c = chart(MACRO).scan()
    c.scan(go=1, a=1)
    assert c.steps == ["eA"] and c["m.X"] and c["oA"]  # the entry step is not left yet
    c.scan(go=0)
    assert c.steps == ["n1"] and c["inner.X"] and c["m.X"] and c["oB"]


def test_nested_macro_steps_and_their_x(chart):
    c = chart(MACRO).scan()
    c.scan(go=1)
    c.scan(go=0, a=1)
    c.scan(b=1)
    assert c.steps == ["n2"] and c["inner.X"] and c["m.X"]
    c.scan()  # inner's outgoing transition is enabled now that its exit n2 is active
    assert c.steps == ["x"] and not c["inner.X"] and c["m.X"]


def test_macro_outgoing_transitions_are_enabled_only_while_its_exit_step_is_active(chart):
    c = chart(MACRO).scan()
    c.scan(go=1)
    c.scan(go=0, out=1)  # m active, but its exit step x is not
    assert c.steps == ["eA"]
    c.scan(a=1, out=0)
    c.scan(a=0, b=1)
    c.scan(b=0, out=1)  # inner -> x fires; m -> s9 is not enabled yet
    assert c.steps == ["x"]
    c.scan()
    assert c.steps == ["s9"] and not c["m.X"] and not c["x.X"]


def test_macro_step_time_and_leave_and_reenter_restarts_it(chart):
    c = chart(MACRO).scan()
    c.scan(go=1)  # m activated at 10 ms
    c.scan(go=0, a=1)
    c.scan(a=0, b=1)
    c.scan(b=0)
    assert c.steps == ["x"] and c.t_ms("m") == 30
    c.scan(back=1)  # m -> m: leaves x, enters eA: m stays active, its .T restarts
    assert c.steps == ["eA"] and c["m.X"] and c.t_ms("m") == 0
    c.scan(back=0)
    assert c.t_ms("m") == 10


def test_macro_step_time_is_kept_after_it_is_left(chart):
    c = chart(MACRO).scan()
    c.scan(go=1).scan(go=0, a=1).scan(a=0, b=1).scan(b=0)
    c.scan(out=1)
    assert c.steps == ["s9"] and c.t_ms("m") == 40
    c.run(3)
    assert c.t_ms("m") == 40


@pytest.mark.parametrize("flag", ["SFCInit", "SFCReset"])
def test_sfcinit_and_sfcreset_empty_every_expansion(chart, flag):
    c = chart(MACRO).scan()
    c.scan(go=1).scan(go=0, a=1)
    assert c.steps == ["n1"]
    c.scan(**{flag: 1})
    assert c.steps == ["s0"] and not c["m.X"] and not c["inner.X"]
    c.scan(**{flag: 0})
    assert c.steps == ["s0"]


def test_an_initial_macro_step_starts_in_its_entry_step(chart):
    c = chart("""\
    grafcet: InitMacro
    inputs: [a]
    steps:
      m:
        initial: true
        macro:
          steps:
            e: {entry: true}
            x: {exit: true}
          transitions:
            - {from: e, to: x, when: a}
      s1: {}
    transitions:
      - {from: m, to: s1, when: "1"}
    """).scan()
    assert c.steps == ["e"] and c["m.X"]
    c.scan(a=1).scan()
    assert c.steps == ["s1"]
    c.scan(SFCInit=1)
    assert c.steps == ["e"] and c["m.X"]


# -- step flags read in pre, .T kept, min and max ----------------------------------------
TIMED = """\
grafcet: Timed
inputs: [go]
outputs: [oWas]
pre:
  - tLong := s1.T >= 100ms
  - tWasX := s1.X
steps:
  s0: {initial: true}
  s1: {}
  s2: {}
transitions:
  - {from: s0, to: s1, when: go}
  - {from: s1, to: s2, when: tLong}
post:
  - oWas := tWasX
"""


def test_step_time_read_in_pre_is_true_exactly_at_its_duration(chart):
    c = chart(TIMED).scan()
    c.scan(go=1)  # s1 activated at 10 ms
    c.run(9, go=0)  # up to 100 ms: .T = 90 ms
    assert c.steps == ["s1"] and not c["tLong"]
    c.scan()  # 110 ms: .T = 100 ms in pre, the transition fires in this same scan
    assert c.steps == ["s2"] and c["tLong"]


def test_step_time_with_an_irregular_clock_is_now_minus_the_activation_scan(chart):
    c = chart(TIMED).scan()
    c.scan_at(10, go=1)
    c.scan_at(37.5, go=0)
    assert c.t_ms("s1") == 27.5
    c.scan_at(109.999)
    assert c.steps == ["s1"]
    c.scan_at(110)
    assert c.steps == ["s2"] and c.t_ms("s1") == 100


def test_step_x_read_in_pre_is_the_situation_before_this_scans_evolution(chart):
    c = chart(TIMED).scan()
    c.scan(go=1)
    assert c["s1.X"] and not c["oWas"]
    c.scan()
    assert c["oWas"]


def test_step_time_is_kept_after_deactivation_until_the_next_activation(chart):
    c = chart(TIMED).scan()
    c.scan(go=1).run(10, go=0)
    assert c.steps == ["s2"] and c.t_ms("s1") == 100
    c.run(5)
    assert c.t_ms("s1") == 100 and c["s1.T"] == 100_000_000
    assert c.t_ms("s0") == 10  # activated at 0 ms, left at 10 ms


def test_min_time_holds_a_true_transition_until_reached(chart):
    c = chart("""\
    grafcet: Min
    steps:
      s0: {initial: true}
      s1: {min: 50ms}
      s2: {}
    transitions:
      - {from: s0, to: s1, when: "1"}
      - {from: s1, to: s2, when: "1"}
    """).scan()
    c.scan()  # s1 at 10 ms
    c.run(4)  # 50 ms: .T = 40
    assert c.steps == ["s1"]
    c.scan()  # 60 ms: .T = 50
    assert c.steps == ["s2"]


MAX = """\
grafcet: Max
inputs: [go]
steps:
  s0: {initial: true}
  s1: {max: 50ms}
  s2: {max: 20ms}
transitions:
  - {from: s0, to: [s1, s2], when: go}
  - {from: s1, to: s0, when: "0"}
  - {from: s2, to: s0, when: "0"}
"""


def test_max_time_sets_sfcerror_strictly_above_and_does_not_force_the_step_out(chart):
    c = chart(MAX.replace("20ms", "200ms")).scan()
    c.scan(go=1)  # s1 at 10 ms
    c.run(5, go=0)  # 60 ms: .T = 50 = max
    assert not c["SFCError"] and c["SFCErrorStep"] == ""
    c.scan()  # .T = 60 > max
    assert c["SFCError"] and c["SFCErrorStep"] == "s1"
    c.run(3)
    assert c.steps == ["s1", "s2"] and c["SFCError"]


def test_max_time_a_second_error_is_not_recorded_until_acknowledged(chart):
    c = chart(MAX).scan()
    c.scan(go=1)
    c.run(3, go=0)  # 40 ms: s2.T = 30 > 20
    assert c["SFCErrorStep"] == "s2"
    c.run(4)  # s1 exceeds too, not recorded
    assert c.t_ms("s1") > 50 and c["SFCErrorStep"] == "s2"
    c.scan(SFCQuitError=1)
    assert not c["SFCError"] and c["SFCErrorStep"] == ""
    c.scan(SFCQuitError=0)  # step times restart: no error yet
    assert not c["SFCError"] and c.t_ms("s1") == 0
    c.run(3)
    assert c["SFCError"] and c["SFCErrorStep"] == "s2"


def test_max_time_only_while_sfcenablelimit(chart):
    c = chart(MAX).scan(SFCEnableLimit=0)
    c.scan(go=1).run(10, go=0)
    assert not c["SFCError"]
    c.scan(SFCEnableLimit=1)
    assert c["SFCError"] and c["SFCErrorStep"] == "s1"  # s1 before s2 in file order


def test_max_error_step_is_the_first_in_file_order_in_the_same_scan(chart):
    c = chart(MAX.replace("50ms", "20ms")).scan()
    c.scan(go=1).run(3, go=0)
    assert c["SFCErrorStep"] == "s1"


def test_sfcerror_cleared_by_sfcreset(chart):
    c = chart(MAX).scan()
    c.scan(go=1).run(3, go=0)
    assert c["SFCError"]
    c.scan(SFCReset=1)
    assert not c["SFCError"] and c["SFCErrorStep"] == ""


MACRO_TIMES = """\
grafcet: MacroTimes
inputs: [go]
steps:
  s0: {initial: true}
  m:
    min: 50ms
    max: 60ms
    macro:
      steps:
        e: {entry: true}
        x: {exit: true}
      transitions:
        - {from: e, to: x, when: "1"}
  s9: {}
transitions:
  - {from: s0, to: m, when: go}
  - {from: m, to: s9, when: "1"}
"""


def test_min_time_of_a_macro_step_holds_its_outgoing_transitions(chart):
    c = chart(MACRO_TIMES).scan()
    c.scan(go=1)  # m at 10 ms
    c.run(4, go=0)  # 50 ms: x active since 20 ms, m.T = 40
    assert c.steps == ["x"]
    c.scan()  # 60 ms: m.T = 50
    assert c.steps == ["s9"]


def test_max_time_of_a_macro_step_is_supervised(chart):
    c = chart(MACRO_TIMES.replace("min: 50ms", "min: 200ms")).scan()
    c.scan(go=1).run(6, go=0)  # 70 ms: m.T = 60
    assert not c["SFCError"]
    c.scan()
    assert c["SFCError"] and c["SFCErrorStep"] == "m"


def test_entering_an_already_active_macro_step_without_leaving_it_keeps_its_time(chart):
    c = chart("""\
    grafcet: MacroAgain
    inputs: [go, again]
    steps:
      s0: {initial: true}
      m:
        macro:
          steps:
            e: {entry: true}
            y: {}
            x: {exit: true}
          transitions:
            - {from: e, to: y, when: "1"}
      s9: {}
    transitions:
      - {from: s0, to: m, when: go}
      - {from: [], to: m, when: again}
      - {from: m, to: s9, when: "0"}
    """).scan()
    c.scan(go=1).scan(go=0).scan()  # m at 10 ms; y active
    assert c.steps == ["y"] and c.t_ms("m") == 20
    c.scan(again=1)  # the entry step again, m was not left
    assert c.steps == ["e", "y"] and c.t_ms("m") == 30


def test_step_time_is_read_where_it_is_read_pre_before_the_evolution_actions_and_post_after(
        chart):
    """.T "whenever it is read in the scan": pre sees the situation before this scan's
    evolution (the value kept from the last activation, or 0 if never active), the actions
    and post the new one (0 in the scan of activation); a step never active has .T = 0."""
    c = chart("""\
    grafcet: TAny
    inputs: [go]
    memory: {tPre: 0s, tAct: 0s, tPost: 0s}
    pre: ["tPre := s1.T"]
    steps:
      s0: {initial: true}
      s1: {actions: ["N tAct := s1.T"]}
    transitions:
      - {from: s0, to: s1, when: go}
      - {from: s1, to: s0, when: go'}
    post: ["tPost := s1.T"]
    """).scan()
    assert (c["tPre"], c["tPost"], c.t_ms("s1")) == (0, 0, 0)
    c.scan(go=1)  # 10 ms: activated
    assert (c["tPre"], c["tAct"], c["tPost"]) == (0, 0, 0)
    c.run(2, go=1)  # 30 ms
    assert (c["tPre"], c["tAct"], c["tPost"]) == (20_000_000, 20_000_000, 20_000_000)
    c.scan(go=0)  # 40 ms: pre still sees it active (30 ms); left, .T kept at 30 ms
    assert (c["tPre"], c["tAct"], c["tPost"]) == (30_000_000, 20_000_000, 30_000_000)
    c.run(2, go=0)
    assert (c["tPre"], c["tPost"]) == (30_000_000, 30_000_000)
    c.scan(go=1)  # 70 ms: activated again
    assert (c["tPre"], c["tAct"], c["tPost"]) == (30_000_000, 0, 0)


PRIORITY_DIV = """\
grafcet: Prio
scan: {model}
inputs: [a, b]
outputs: [o2, o3, o4]
memory: {{parts: 0, count: 0}}
steps:
  s0: {{initial: true}}
  s1: {{initial: true}}
  s2: {{actions: [o2]}}
  s3: {{actions: [o3]}}
  s4: {{actions: [o4]}}
transitions:
  - {{from: s0, to: s2, when: a}}
  - {{from: [s0, s1], to: s3, when: b}}
  - {{from: s0, to: s4, when: "count / parts > 2"}}
"""


@pytest.mark.parametrize("model", ["immediate", "stable", "codesys"])
def test_a_condition_priority_never_evaluates_cannot_fault_the_scan(
        tmp_path: Path, model: str) -> None:
    """t1 fires, so t2 (lower priority on the shared step s0) is not evaluated: its
    division by zero must not fault the scan. The immediate model's "does anything fire?"
    pre-test evaluated it (a review of the scan closures found it)."""
    from runtime.compiler.codegen import compile_grafcet
    from runtime.engine.instance import Instance
    from runtime.language.grafcetfile import load_grafcet

    path = tmp_path / "c.yaml"
    path.write_text(PRIORITY_DIV.format(model=model), encoding="utf-8")
    inst = Instance("i", compile_grafcet(load_grafcet(str(path))))
    for k in range(3):
        inst.set("b", k >= 1)
        inst.scan(1_000_000_000 + k * 10_000_000, k * 10_000_000)
    assert inst.active_steps() == ["s3"]
