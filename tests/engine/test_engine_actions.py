"""semantics.md, "Actions": every qualifier at its exact boundary scan (immediate model).

The chart is s0 -> s1 on ``go``, s1 -> s2 on ``leave``, s2 -> s0 on ``back``; scan k at
k·10 ms, so a step activated at scan k has .T = 10·(j - k) ms at scan j.
"""

from __future__ import annotations

import pytest


def three_steps(s1: list[str], s2: list[str] | None = None, s0: list[str] | None = None,
                outputs: str = "o, p, q", memory: str = "n: 0", scan: str = "immediate",
                post: str = "") -> str:
    def acts(lst: list[str] | None) -> str:
        return "[" + ", ".join(f'"{a}"' for a in (lst or [])) + "]"

    return f"""\
grafcet: Q
scan: {scan}
inputs: [go, leave, back, c, ev]
outputs: [{outputs}]
memory: {{{memory}}}
steps:
  s0: {{initial: true, actions: {acts(s0)}}}
  s1: {{actions: {acts(s1)}}}
  s2: {{actions: {acts(s2)}}}
transitions:
  - {{from: s0, to: s1, when: go}}
  - {{from: s1, to: s2, when: leave}}
  - {{from: s2, to: s0, when: back}}
{post}"""


def trace(c, key: str, scans: list[dict]) -> list:  # type: ignore[no-untyped-def]
    out = []
    for values in scans:
        c.scan(**values)
        out.append(int(c[key]) if isinstance(c[key], bool) else c[key])
    return out


# -- N ---------------------------------------------------------------------------------
def test_n_bool_is_true_exactly_while_the_step_is_active(chart):
    c = chart(three_steps(["N o"], s2=[]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}, {"leave": 0}])
    assert got == [0, 1, 1, 1, 0, 0]


def test_n_is_the_default_qualifier(chart):
    c = chart(three_steps(["o"]))
    assert trace(c, "o", [{}, {"go": 1}, {"leave": 1}]) == [0, 1, 0]


def test_n_statement_is_executed_every_scan_while_active(chart):
    c = chart(three_steps(["N n := n + 1"]))
    got = trace(c, "n", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}, {}])
    assert got == [0, 1, 2, 3, 3, 3]


def test_conditional_n_is_true_while_active_and_the_condition_holds(chart):
    c = chart(three_steps(["N o if c"]))
    got = trace(c, "o", [{"c": 1}, {"go": 1, "c": 0}, {"c": 1}, {"c": 0}, {"c": 1},
                         {"leave": 1}])
    assert got == [0, 0, 1, 0, 1, 0]


# -- S / R -------------------------------------------------------------------------------
def test_s_is_stored_after_the_step_is_left_until_an_r(chart):
    c = chart(three_steps(["S o"], s0=["R o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {"leave": 1}, {"leave": 0}, {"back": 1}])
    assert got == [0, 1, 1, 1, 1, 0]


def test_r_dominates_s_in_the_same_scan(chart):
    c = chart("""\
    grafcet: SR
    inputs: [go, stop]
    outputs: [o]
    steps:
      s0: {initial: true}
      a: {actions: ["S o"]}
      b: {actions: ["R o"]}
      c: {}
    transitions:
      - {from: s0, to: [a, b], when: go}
      - {from: b, to: c, when: stop}
    """)
    assert trace(c, "o", [{}, {"go": 1}, {"go": 0}, {"stop": 1}, {}]) == [0, 0, 0, 1, 1]


def test_r_of_a_step_also_stops_the_n_of_another(chart):
    # Q = NOT R AND (...): R of the shared action control overrides every qualifier
    c = chart("""\
    grafcet: RN
    inputs: [go]
    outputs: [o]
    steps:
      s0: {initial: true, actions: [o]}
      r: {actions: ["R o"]}
    transitions:
      - {from: [], to: r, when: go}
      - {from: r, to: [], when: go'}
    """)
    assert trace(c, "o", [{}, {"go": 1}, {"go": 0}]) == [1, 0, 1]


# -- L / D -------------------------------------------------------------------------------
def test_l_is_true_while_active_and_t_below_the_limit(chart):
    c = chart(three_steps(["L 30ms o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {}, {}])
    assert got == [0, 1, 1, 1, 0, 0]  # .T = 0, 10, 20 -> true; 30 -> false


def test_l_ends_with_the_step(chart):
    c = chart(three_steps(["L 1s o"]))
    assert trace(c, "o", [{}, {"go": 1}, {"leave": 1}]) == [0, 1, 0]


def test_l_statement_is_executed_while_t_below_the_limit(chart):
    c = chart(three_steps(["L 30ms n := n + 1"]))
    assert trace(c, "n", [{}, {"go": 1}, {"go": 0}, {}, {}, {}]) == [0, 1, 2, 3, 3, 3]


def test_d_is_true_once_t_reaches_the_delay_while_active(chart):
    c = chart(three_steps(["D 30ms o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {}, {}, {"leave": 1}])
    assert got == [0, 0, 0, 0, 1, 1, 0]


def test_d_statement(chart):
    c = chart(three_steps(["D 20ms n := n + 1"]))
    assert trace(c, "n", [{}, {"go": 1}, {"go": 0}, {}, {}, {"leave": 1}]) == [0, 0, 0, 1, 2, 2]


# -- P / P1 / P0 ---------------------------------------------------------------------------
def test_p_bool_is_a_one_scan_pulse_on_activation(chart):
    c = chart(three_steps(["P o"]))
    assert trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}]) == [0, 1, 0, 0, 0]


def test_p_statement_is_executed_once_on_activation(chart):
    c = chart(three_steps(["P n := n + 1"]))
    assert trace(c, "n", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}, {}]) == [0, 1, 1, 1, 1, 1]


def test_p1_and_p0_run_once_on_activation_and_once_on_deactivation(chart):
    c = chart(three_steps(["P1 n := n + 1", "P0 n := n + 100"]))
    got = trace(c, "n", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}, {"leave": 0}])
    assert got == [0, 1, 1, 1, 101, 101]


def test_p1_p0_again_on_every_new_activation(chart):
    c = chart(three_steps(["P1 n := n + 1", "P0 n := n + 100"]))
    c.scan().scan(go=1).scan(go=0, leave=1).scan(leave=0, back=1).scan(back=0, go=1)
    assert c["n"] == 102


# -- SD / DS / SL ---------------------------------------------------------------------------
def test_sd_is_stored_after_t_from_activation_even_if_the_step_is_left(chart):
    c = chart(three_steps(["SD 30ms o"], s0=["R o"]))
    # s1 active 10 ms only; o rises 30 ms after activation and stays until the R in s0
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0, "leave": 1}, {"leave": 0}, {}, {}, {},
                         {"back": 1}])
    assert got == [0, 0, 0, 0, 1, 1, 1, 0]


def test_sd_timer_is_not_restarted_by_a_new_activation_before_r(chart):
    c = chart(three_steps(["SD 40ms o"]))
    c.scan().scan(go=1)  # 10 ms
    c.scan(go=0, leave=1).scan(leave=0, back=1).scan(back=0, go=1)  # 40 ms: s1 again
    assert not c["o"]
    c.scan(go=0)  # 50 ms: 40 ms after the first activation
    assert c["o"]


def test_ds_is_stored_after_t_only_if_the_step_is_still_active(chart):
    c = chart(three_steps(["DS 30ms o"], s0=["R o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}, {"leave": 0}, {}])
    assert got == [0, 0, 0, 0, 0, 0, 0]  # left at .T = 30 ms: in that scan s1 is inactive
    c = chart(three_steps(["DS 30ms o"], s0=["R o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {}, {"leave": 1}, {"leave": 0},
                         {"back": 1}])
    assert got == [0, 0, 0, 0, 1, 1, 1, 0]


def test_sl_is_stored_at_activation_for_t(chart):
    c = chart(three_steps(["SL 30ms o"]))
    # left after 10 ms, still true until 30 ms after activation
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0, "leave": 1}, {"leave": 0}, {}, {}])
    assert got == [0, 1, 1, 1, 0, 0]


def test_sl_is_ended_by_r(chart):
    c = chart(three_steps(["SL 1s o"], s2=["R o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {"leave": 1}, {}, {"back": 1}, {}])
    assert got == [0, 1, 1, 0, 0, 0, 0]


def test_sd_is_ended_by_r(chart):
    c = chart(three_steps(["SD 10ms o"], s2=["R o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"go": 0}, {}, {"leave": 1}, {"back": 1}, {}])
    assert got == [0, 0, 1, 1, 0, 0, 0]  # stays off once the R is over


def test_sd_ds_sl_timers_are_per_association(chart):
    # two SD associations of the same target in two steps: each has its own timer
    c = chart("""\
    grafcet: Per
    inputs: [go]
    outputs: [o]
    steps:
      s0: {initial: true}
      a: {actions: ["SD 50ms o"]}
      b: {actions: ["SD 20ms o"]}
    transitions:
      - {from: s0, to: a, when: "1"}
      - {from: a, to: b, when: go}
    """)
    c.scan().scan()  # a at 10 ms
    c.scan(go=1)  # b at 20 ms
    c.scan(go=0)  # 30 ms
    assert not c["o"]
    c.scan()  # 40 ms: b's SD done
    assert c["o"]


# -- events ----------------------------------------------------------------------------
def test_on_event_runs_in_every_scan_of_the_active_step_where_the_edge_holds(chart):
    c = chart(three_steps(["on ↑ev do n := n + 1"]))
    got = trace(c, "n", [{"ev": 1}, {"go": 1, "ev": 0}, {"ev": 1}, {"ev": 1}, {"ev": 0},
                         {"ev": 1}, {"leave": 1, "ev": 0}, {"ev": 1}])
    assert got == [0, 0, 1, 1, 1, 2, 2, 2]


def test_on_falling_event(chart):
    c = chart(three_steps(["on ↓ev do n := n + 1"]))
    assert trace(c, "n", [{"ev": 1}, {"go": 1}, {"ev": 0}, {}]) == [0, 0, 1, 1]


# -- action controls and targets ----------------------------------------------------------
def test_one_action_control_per_bool_target_is_the_or_over_steps(chart):
    c = chart(three_steps(["o"], s2=["o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"leave": 1}, {"back": 1}])
    assert got == [0, 1, 1, 0]


def test_one_action_control_mixes_qualifiers_of_several_steps(chart):
    c = chart(three_steps(["S o"], s2=["N o"], s0=["R o"]))
    got = trace(c, "o", [{}, {"go": 1}, {"leave": 1}, {"back": 1}])
    assert got == [0, 1, 1, 0]


def test_a_statement_written_in_two_steps_is_two_actions(chart):
    c = chart("""\
    grafcet: Two
    inputs: [go]
    memory: {n: 0}
    steps:
      s0: {initial: true}
      a: {actions: ["N n := n + 1"]}
      b: {actions: ["N n := n + 1"]}
    transitions:
      - {from: s0, to: [a, b], when: go}
    """)
    assert trace(c, "n", [{}, {"go": 1}, {"go": 0}]) == [0, 2, 4]


def test_a_p1_statement_in_two_steps_activated_together_runs_twice(chart):
    c = chart("""\
    grafcet: TwoP
    inputs: [go]
    memory: {n: 0}
    steps:
      s0: {initial: true}
      a: {actions: ["P1 n := n + 1"]}
      b: {actions: ["P1 n := n + 1"]}
    transitions:
      - {from: s0, to: [a, b], when: go}
    """)
    assert trace(c, "n", [{}, {"go": 1}, {"go": 0}]) == [0, 2, 2]


def test_an_undriven_output_stays_false(chart):
    c = chart(three_steps(["o"]))
    assert trace(c, "q", [{}, {"go": 1}, {"leave": 1}, {"back": 1}]) == [0, 0, 0, 0]


def test_a_bool_memory_can_be_an_action_target(chart):
    c = chart(three_steps(["S mFlag"], memory="mFlag: false"))
    assert trace(c, "mFlag", [{}, {"go": 1}, {"leave": 1}]) == [0, 1, 1]


def test_post_overrides_the_action_value(chart):
    c = chart(three_steps(["o"], post="post:\n  - o := o·c + s2.X\n"))
    got = trace(c, "o", [{}, {"go": 1}, {"c": 1}, {"c": 0, "leave": 1}])
    assert got == [0, 0, 1, 1]


def test_pre_sees_last_scans_action_value_and_actions_overwrite_it(chart):
    c = chart(three_steps(["o"], s0=[], post="pre:\n  - tWas := o\n  - o := 1\n"))
    got = trace(c, "tWas", [{}, {"go": 1}, {}, {"leave": 1}, {}])
    assert got == [0, 0, 1, 1, 0]
    assert not c["o"]  # the action control writes o every scan, after pre


# -- order of statement actions ---------------------------------------------------------------
ORDER = """\
grafcet: Order
inputs: [go]
memory: {{seq: 0}}
steps:
  s0: {{initial: true}}
{steps}
transitions:
  - {{from: s0, to: sA, when: "1"}}
  - {{from: sA, to: sB, when: go}}
"""


@pytest.mark.parametrize("a_first", [True, False])
def test_statement_actions_run_in_file_order_p0_of_steps_just_left_included(chart, a_first):
    sa = '  sA: {actions: ["P0 seq := seq * 10 + 1", "N seq := seq * 10 + 2"]}'
    sb = '  sB: {actions: ["N seq := seq * 10 + 3", "P1 seq := seq * 10 + 4"]}'
    c = chart(ORDER.format(steps="\n".join([sa, sb] if a_first else [sb, sa])))
    c.scan().scan()
    assert c["seq"] == 2
    c.scan(seq=0, go=1)
    assert c["seq"] == (134 if a_first else 341)


def test_statement_actions_of_a_macro_expansion_run_in_place(chart):
    c = chart("""\
    grafcet: MacroOrder
    memory: {seq: 0}
    steps:
      s0: {initial: true, actions: ["N seq := seq * 10 + 1"]}
      m:
        initial: true
        macro:
          steps:
            e: {entry: true, actions: ["N seq := seq * 10 + 2"]}
            x: {exit: true}
      s9: {initial: true, actions: ["N seq := seq * 10 + 3"]}
    """).scan()
    assert c["seq"] == 123


def test_bool_targets_take_their_value_before_statement_actions_run(chart):
    c = chart(three_steps(["N n := n + o", "o"]))
    assert trace(c, "n", [{}, {"go": 1}, {}]) == [0, 1, 2]
