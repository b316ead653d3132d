"""semantics.md, "Chart flags": SFCInit, SFCReset, SFCPause, SFCError & co, SFCTip."""

from __future__ import annotations

import pytest

FLAGS = """\
grafcet: Flags
inputs: [go, leave, iP]
outputs: [oN0, oS, oN1, oL, oSD]
memory: {{n0: 0, p0: 0, n1: 0, p1: 0, q1: 0, cPre: 0, cPost: 0}}
{pre}
steps:
  s0: {{initial: true, actions: [oN0, "N n0 := n0 + 1", "P1 p0 := p0 + 1"]}}
  s1:
    actions: ["S oS", oN1, "L 50ms oL", "SD 30ms oSD", "N n1 := n1 + 1", "P1 p1 := p1 + 1",
              "P0 q1 := q1 + 1"]
  s2: {{}}
transitions:
  - {{from: s0, to: s1, when: go}}
  - {{from: s1, to: s2, when: leave}}
  - {{from: s2, to: s0, when: "1"}}
{post}
"""


def flags(pre: str = "", post: str = "") -> str:
    return FLAGS.format(pre=f"pre: [{pre}]" if pre else "", post=f"post: [{post}]" if post
                        else "")


def in_s1(c):  # type: ignore[no-untyped-def]
    """Scan 0, then s1 activated at 10 ms, then two scans: s1.T = 20 ms at 30 ms."""
    c.scan().scan(go=1).scan(go=0).scan()
    assert c.steps == ["s1"] and c.t_ms("s1") == 20
    return c


# -- SFCInit ---------------------------------------------------------------------------------
def test_sfcinit_while_true_initial_situation_no_action_bool_targets_false(chart):
    c = in_s1(chart(flags()))
    n0, p0 = c["n0"], c["p0"]
    for _ in range(3):
        c.scan(SFCInit=1, go=1)  # no transition fires while SFCInit
        assert c.steps == ["s0"] and c.t_ms("s0") == 0
        assert not any(c[o] for o in ("oN0", "oS", "oN1", "oL", "oSD"))
        assert (c["n0"], c["p0"]) == (n0, p0)  # no statement action, no P1
    assert c["q1"] == 0  # choice: P0 of the steps left by SFCInit does not run


def test_sfcinit_falling_scan_activates_the_initial_steps(chart):
    c = in_s1(chart(flags()))
    c.scan(SFCInit=1).scan(SFCInit=1)
    p0 = c["p0"]
    c.scan(SFCInit=0, go=1)  # P1 runs, .T restarts; no transition fires in this scan
    assert c.steps == ["s0"] and c["p0"] == p0 + 1 and c["oN0"] and c.t_ms("s0") == 0
    c.scan()
    assert c.steps == ["s1"] and c.t_ms("s0") == 10


def test_sfcinit_resets_stored_actions_and_action_timers(chart):
    c = chart(flags()).scan().scan(go=1)  # s1 at 10 ms: S oS, SD 30ms oSD running
    c.scan(go=0, leave=1)  # s1 left at 20 ms
    assert c["oS"] and not c["oSD"]
    c.scan(leave=0, SFCInit=1)
    c.scan(SFCInit=0)
    c.run(5)
    assert not c["oS"] and not c["oSD"]


def test_sfcinit_resets_error_pause_and_quit(chart):
    c = chart(flags()).scan()
    c.scan(SFCError=1, SFCPause=1, SFCQuitError=1)
    c.scan(SFCInit=1)
    assert not (c["SFCError"] or c["SFCPause"] or c["SFCQuitError"])
    assert c["SFCErrorStep"] == ""


# -- SFCReset --------------------------------------------------------------------------------
def test_sfcreset_initial_situation_with_its_actions_executing(chart):
    c = in_s1(chart(flags()))
    n0, p0 = c["n0"], c["p0"]
    c.scan(SFCReset=1, go=1)
    assert c.steps == ["s0"] and c["oN0"] and c["n0"] == n0 + 1 and c["p0"] == p0 + 1
    assert not c["oS"] and c["q1"] == 0  # stored actions reset; choice: no P0 of s1
    c.scan(SFCReset=1)
    c.scan(SFCReset=1)
    assert c.steps == ["s0"] and c.t_ms("s0") == 0
    assert c["n0"] == n0 + 3 and c["p0"] == p0 + 1  # activated in the first scan only
    c.scan(SFCReset=0)  # go still true: evolution resumes in the falling scan
    assert c.steps == ["s1"]


def test_sfcreset_resets_action_timers(chart):
    c = chart(flags()).scan().scan(go=1).scan(go=0, leave=1)
    c.scan(leave=0, SFCReset=1).scan(SFCReset=0)
    c.run(5)
    assert not c["oSD"]


# -- SFCPause --------------------------------------------------------------------------------
def test_sfcpause_no_transition_times_frozen_targets_held_no_statement(chart):
    c = in_s1(chart(flags(pre="cPre := cPre + 1", post="cPost := cPost + 1")))
    n1, pre = c["n1"], c["cPre"]
    c.scan(SFCPause=1, leave=1)  # 40 ms: the interval up to this scan still counts
    assert c.steps == ["s1"] and c.t_ms("s1") == 30
    c.set(leave=0)
    for _ in range(3):
        c.scan()
        assert c.steps == ["s1"] and c.t_ms("s1") == 30
        assert c["oN1"] and c["oL"]  # held
    assert c["n1"] == n1  # no statement action while paused
    assert c["cPre"] == pre + 4 and c["cPost"] == c["cPre"]  # pre and post still run
    c.scan(SFCPause=0)  # 80 ms
    assert c.t_ms("s1") == 30 and c["n1"] == n1 + 1
    c.scan()
    assert c.t_ms("s1") == 40 and c["oL"]
    c.scan()
    assert not c["oL"]  # L 50 ms ran out 50 ms of unpaused time after activation


def test_sfcpause_bool_targets_hold_their_last_value_even_if_the_step_is_left(chart):
    c = chart(flags()).scan()
    c.scan(go=1, SFCPause=1)
    assert c.steps == ["s0"] and c["oN0"]
    c.scan(SFCPause=1, SFCInit=0)
    assert c["oN0"] and not c["oN1"]


def test_sfcpause_freezes_sd_timers(chart):
    c = chart(flags()).scan().scan(go=1)  # SD 30ms from 10 ms
    c.scan(go=0)  # 20 ms
    c.scan(SFCPause=1).scan().scan()  # 30, 40, 50
    c.scan(SFCPause=0)  # 60: only 20 ms of unpaused time
    assert not c["oSD"]
    c.scan()
    assert c["oSD"]


def test_sfcpause_edges_are_still_sampled(chart):
    c = chart("""\
    grafcet: PauseEdge
    inputs: [b]
    steps:
      s0: {initial: true}
      s1: {}
    transitions:
      - {from: s0, to: s1, when: ↑b}
    """).scan()
    c.scan(b=1, SFCPause=1)
    c.scan(SFCPause=0)
    assert c.steps == ["s0"]  # the edge happened while paused and is gone


# -- SFCError, SFCQuitError, SFCEnableLimit --------------------------------------------------------
def test_sfcquiterror_pauses_while_true_clears_the_error_and_restarts_times_on_falling(chart):
    c = in_s1(chart(flags()))
    c.scan(SFCError=1)  # an equation or the console may set it
    c.scan(SFCQuitError=1, leave=1)
    assert not c["SFCError"] and c.steps == ["s1"] and c.t_ms("s1") == 40
    n1 = c["n1"]
    c.scan(SFCQuitError=1)
    assert c.steps == ["s1"] and c.t_ms("s1") == 40 and c["n1"] == n1
    c.scan(SFCQuitError=0, leave=0)
    assert c.t_ms("s1") == 0 and c["n1"] == n1 + 1
    c.scan()
    assert c.t_ms("s1") == 10


def test_sfcerror_does_not_pause_the_chart(chart):
    c = chart(flags()).scan(SFCError=1)
    c.scan(go=1)
    assert c.steps == ["s1"] and c["SFCError"]


# -- SFCCurrentStep -------------------------------------------------------------------------------
def test_sfccurrentstep_is_the_last_active_step_in_file_order(chart):
    c = chart("""\
    grafcet: Cur
    inputs: [go]
    steps:
      a: {initial: true}
      b: {}
      c: {}
    transitions:
      - {from: a, to: [c, b], when: go}
      - {from: c, to: [], when: "1"}
    """)
    c.scan()
    assert c["SFCCurrentStep"] == "a"
    c.scan(go=1)
    assert c["SFCCurrentStep"] == "c"
    c.scan(go=0)
    assert c["SFCCurrentStep"] == "b"


# -- SFCTipMode / SFCTip --------------------------------------------------------------------------
def test_tip_mode_a_transition_fires_only_on_a_rising_sfctip(chart):
    c = chart("""\
    grafcet: Tip
    steps:
      s0: {initial: true}
      s1: {}
      s2: {}
    transitions:
      - {from: s0, to: s1, when: "1"}
      - {from: s1, to: s2, when: "1"}
    """)
    c.scan(SFCTipMode=1, SFCTip=1).scan().scan()
    assert c.steps == ["s0"]  # SFCTip held since power-up: no edge
    c.scan(SFCTip=0).scan()
    assert c.steps == ["s0"]
    c.scan(SFCTip=1)
    assert c.steps == ["s1"]
    c.scan().scan()
    assert c.steps == ["s1"]
    c.scan(SFCTip=0).scan(SFCTip=1)
    assert c.steps == ["s2"]


def test_tip_mode_off_evolves_normally(chart):
    c = chart("""\
    grafcet: Tip
    steps:
      s0: {initial: true}
      s1: {}
    transitions:
      - {from: s0, to: s1, when: "1"}
    """)
    c.scan(SFCTipMode=1).scan().scan(SFCTipMode=0)
    assert c.steps == ["s1"]


# -- where a flag is written --------------------------------------------------------------------
@pytest.mark.parametrize("flag", ["SFCPause", "SFCInit", "SFCReset"])
def test_a_flag_written_in_pre_takes_effect_in_the_same_scan(chart, flag):
    c = chart(flags(pre=f"{flag} := iP")).scan()
    c.scan(go=1, iP=1)
    assert c.steps == ["s0"]


@pytest.mark.parametrize("flag", ["SFCPause", "SFCInit", "SFCReset"])
def test_a_flag_written_in_post_takes_effect_in_the_next_scan(chart, flag):
    c = chart(flags(post=f"{flag} := iP")).scan()
    c.scan(go=1, iP=1)
    assert c.steps == ["s1"]
    c.scan(go=0, iP=0, leave=1)
    assert c.steps == (["s1"] if flag == "SFCPause" else ["s0"])


def test_a_flag_written_in_an_action_takes_effect_in_the_next_scan(chart):
    c = chart("""\
    grafcet: ActFlag
    steps:
      s0: {initial: true}
      s1: {actions: ["P1 SFCPause := 1"]}
      s2: {}
    transitions:
      - {from: s0, to: s1, when: "1"}
      - {from: s1, to: s2, when: "1"}
    """).scan()
    c.scan()
    assert c.steps == ["s1"] and c["SFCPause"]
    c.scan().scan()
    assert c.steps == ["s1"]
    c.scan(SFCPause=0)
    assert c.steps == ["s2"]
