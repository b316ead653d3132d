"""Instance services: retain snapshot/restore, restart, explain()."""

from __future__ import annotations

RET = """\
grafcet: Ret
inputs: [start, a]
outputs: [o]
memory:
  nKept: {init: 5, retain: true}
  tmKept: {init: 1s, retain: true}
  bKept: {init: false, retain: true}
  nLost: 7
steps:
  s0: {initial: true}
  s1: {actions: [o, "P1 nKept := nKept + 1", "P1 nLost := nLost + 1", "P1 bKept := 1"]}
transitions:
  - {from: s0, to: s1, when: ↑start}
"""


def test_retain_snapshot_holds_only_retained_memory(chart):
    c = chart(RET).scan().scan(start=1)
    assert c.inst.retain_snapshot() == {"nKept": 6, "tmKept": 1_000_000_000, "bKept": True}


def test_restore_retain_converts_and_reports_what_it_ignored(chart):
    c = chart(RET)
    ignored = c.inst.restore_retain({"nKept": 41.0, "tmKept": "2s", "bKept": 1, "nLost": 3,
                                     "ghost": 1})
    assert sorted(ignored) == ["ghost", "nLost"]
    assert c["nKept"] == 41 and type(c["nKept"]) is int
    assert c["tmKept"] == 2_000_000_000 and c["bKept"] is True and c["nLost"] == 7
    assert c.inst.restore_retain({"nKept": "many", "bKept": 2}) == ["nKept", "bKept"]
    assert c["nKept"] == 41 and c["bKept"] is True


def test_retained_memory_survives_a_new_instance_through_a_snapshot(chart):
    c = chart(RET).scan().scan(start=1)
    snap = c.inst.retain_snapshot()
    d = chart(RET)
    d.inst.restore_retain(snap)
    d.scan()
    assert d["nKept"] == 6 and d["nLost"] == 7 and d.steps == ["s0"]


def test_restart_initial_situation_keeps_retained_memory(chart):
    c = chart(RET).scan().scan(start=1)
    assert c.steps == ["s1"] and c["o"] and c["nLost"] == 8
    c.inst.restart()
    assert c["s0.X"] and not c["s1.X"] and not c["o"]  # before its first scan
    assert c["nKept"] == 6 and c["bKept"] and c["nLost"] == 7
    c.scan(start=1)  # the button held across the restart: no edge on the first scan
    assert c.steps == ["s0"]
    c.scan(start=0).scan(start=1)
    assert c.steps == ["s1"] and c["nKept"] == 7


def test_restart_restarts_the_chart_clock(chart):
    c = chart(RET).scan().scan(start=1).run(10)
    c.inst.restart()
    c.scan_at(5000)
    assert c.t_ms("s0") == 0
    c.scan_at(5010)
    assert c.t_ms("s0") == 10


# -- explain -----------------------------------------------------------------------------
EXPL = """\
grafcet: Expl
inputs: [a, b, c]
steps:
  s0: {initial: true}
  s1: {min: 50ms}
  s2: {}
  s3: {}
transitions:
  - {from: s0, to: s1, when: "a·b' + c"}
  - {from: s1, to: s2, when: a}
  - {from: s1, to: s3, when: b}
"""


def test_explain_reports_the_sub_terms_of_the_condition(chart):
    c = chart(EXPL).scan(a=1, b=1)
    (why,) = c.inst.explain()
    assert why.step == "s0" and why.time_ns == 0
    (t,) = why.transitions
    assert t.text == "s0 -> s1 when a·b' + c" and t.condition is False and t.blocked == []
    terms = [(x.text, x.depth, x.value) for x in t.terms]
    assert terms == [("a·b' + c", 0, 0), ("a·b'", 1, 0), ("a", 2, 1), ("b'", 2, 0),
                     ("b", 3, 1), ("c", 1, 0)]


def test_explain_reports_min_time_and_the_earlier_transition(chart):
    c = chart(EXPL).scan().scan(c=1)
    c.scan(c=0, a=1, b=1)
    (why,) = c.inst.explain()
    assert why.step == "s1" and why.time_ns == 10_000_000
    t2, t3 = why.transitions
    assert t2.condition and any("min time of s1: 10ms of 50ms" in b for b in t2.blocked)
    assert t3.condition and any("min time of s1" in b for b in t3.blocked)
    assert not any("earlier" in b for b in t2.blocked + t3.blocked)  # t2 cannot fire yet
    c.run(4, a=0, b=0)  # 60 ms: .T = 50 ms, nothing true
    t2, t3 = c.inst.explain()[0].transitions
    assert not t2.condition and t2.blocked == [] and t3.blocked == []
    c.set(a=1, b=1)  # explain evaluates on the stored values
    t2, t3 = c.inst.explain()[0].transitions
    assert t2.condition and t2.blocked == []
    assert t3.blocked == ["earlier transition has priority: s1 -> s2 when a"]


def test_explain_reports_an_initial_situation_held_by_sfcinit(chart):
    c = chart(EXPL).scan().scan(SFCInit=1, c=1)
    (why,) = c.inst.explain()
    assert any(b.startswith("SFCInit") for b in why.transitions[0].blocked)


def test_explain_reports_pause_and_tip_mode(chart):
    c = chart(EXPL).scan().scan(SFCPause=1, a=1)
    (why,) = c.inst.explain()
    assert any("paused" in b for b in why.transitions[0].blocked)
    c.scan(SFCPause=0, SFCTipMode=1, a=0)
    (why,) = c.inst.explain()
    assert any("SFCTip" in b for b in why.transitions[0].blocked)
    assert not any("paused" in b for b in why.transitions[0].blocked)


def test_explain_edges_as_sampled_in_the_last_scan(chart):
    c = chart(EXPL.replace("a·b' + c", "↑a")).scan()
    c.scan(SFCPause=1, a=1)
    (why,) = c.inst.explain()
    assert why.transitions[0].condition is True
    c.scan()
    (why,) = c.inst.explain()
    assert why.transitions[0].condition is False
