"""semantics.md, "scan: stable": the search for a stable situation within one scan."""

from __future__ import annotations

import pytest

from runtime.compiler.evolution import STABLE_MAX_ROUNDS, UnstableChart

PASS = """\
grafcet: Pass
scan: stable
inputs: [a, b]
outputs: [oS, oCont, oP, oL, oD, oRst]
memory: {{m: 0, seq: 0, nEv: 0}}
steps:
  s0: {{initial: true, actions: ["S oRst", "P0 seq := seq * 10 + 1"]}}
  s1:
    actions: ["S oS", oCont, "P oP", "L 1s oL", "D 0ms oD", "R oRst", "P1 seq := seq * 10 + 2",
              "P0 seq := seq * 10 + 3", "P1 m := 1", "on ↑b do nEv := nEv + 1"]
  s2: {{actions: ["N seq := seq * 10 + 4", "P1 seq := seq * 10 + 5"]}}
  s3: {{}}
transitions:
  - {{from: s0, to: s1, when: ↑a}}
  - {{from: s1, to: s2, when: {t1}}}
  - {{from: s2, to: s3, when: {t2}}}
"""


def test_stable_search_crosses_several_steps_in_one_scan(chart):
    c = chart(PASS.format(t1="1", t2="a")).scan()
    c.scan(a=1)
    assert c.steps == ["s3"]


def test_stable_edges_are_true_in_the_first_round_only(chart):
    c = chart(PASS.format(t1="1", t2="↑a")).scan()
    c.scan(a=1)
    assert c.steps == ["s2"]  # ↑a fired s0 -> s1 in round 1, not s2 -> s3 in round 3
    c.scan(a=0).scan(a=1)
    assert c.steps == ["s3"]


def test_stable_rounds_see_the_variables_as_before_the_search(chart):
    c = chart(PASS.format(t1="m = 1", t2="0")).scan()
    c.scan(a=1)  # s1's P1 sets m, but only after the search
    assert c.steps == ["s1"] and c["m"] == 1
    c.scan()
    assert c.steps == ["s2"]


def test_stable_stored_actions_take_effect_for_every_step_passed_through(chart):
    c = chart(PASS.format(t1="1", t2="0")).scan()
    assert c["oRst"]
    c.scan(a=1, b=1)
    assert c.steps == ["s2"]
    assert c["oS"] and not c["oRst"]  # S and R of s1, passed through
    assert c["oP"]  # the P pulse of s1
    # P0 of s0, P1 and P0 of s1, then N and P1 of s2: file order, as written
    assert c["seq"] == 12345


def test_stable_event_action_of_a_step_passed_through(chart):
    c = chart(PASS.format(t1="1", t2="0")).scan()
    c.scan(a=1, b=1)
    assert c["nEv"] == 1


def test_stable_continuous_actions_only_on_the_stable_situation(chart):
    c = chart(PASS.format(t1="1", t2="0")).scan()
    c.scan(a=1)
    assert not c["oCont"] and not c["oL"] and not c["oD"]


def test_stable_cycle_0_has_no_evolution(chart):
    c = chart(PASS.format(t1="1", t2="1").replace("↑a", "a")).scan(a=1)
    assert c.steps == ["s0"]
    c.scan()
    assert c.steps == ["s3"]


def test_stable_rule5_and_time_of_the_steps_of_the_search(chart):
    c = chart(PASS.format(t1="1", t2="0")).scan().run(3)
    c.scan(a=1)
    assert c.t_ms("s2") == 0 and c.t_ms("s1") == 0 and c.t_ms("s0") == 40


def test_unstable_chart_raises_after_the_round_limit_naming_the_transitions(chart):
    c = chart("""\
    grafcet: Loop
    scan: stable
    inputs: [go]
    steps:
      s0: {initial: true}
      s1: {}
      s2: {}
      s9: {}
    transitions:
      - {from: s0, to: s1, when: go}
      - {from: s1, to: s2, when: "1"}
      - {from: s2, to: s1, when: "1"}
    """).scan()
    c.scan()
    with pytest.raises(UnstableChart) as e:
        c.scan(go=1)
    msg = str(e.value)
    assert "Loop" in msg and str(STABLE_MAX_ROUNDS) in msg
    assert "s1 -> s2 when 1" in msg or "s2 -> s1 when 1" in msg
    assert "s0 -> s1" not in msg
    assert set(e.value.cycle) <= {"s1 -> s2 when 1", "s2 -> s1 when 1"} and e.value.cycle
    assert e.value.steps == ["s1", "s2"] and "cycle of steps s1, s2" in msg


def test_a_long_but_finite_search_is_not_unstable(chart):
    n = STABLE_MAX_ROUNDS
    steps = "\n".join(f"  s{i}: {{}}" for i in range(1, n + 1))
    trans = "\n".join(f"  - {{from: s{i}, to: s{i + 1}, when: \"1\"}}" for i in range(n))
    c = chart(f"grafcet: Long\nscan: stable\nsteps:\n  s0: {{initial: true}}\n{steps}\n"
              f"transitions:\n{trans}\n").scan()
    c.scan()
    assert c.steps == [f"s{n}"]
