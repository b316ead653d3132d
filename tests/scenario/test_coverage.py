"""SFC coverage: the counters a program compiled with coverage keeps (each step's
activations, each transition's firings, each action's runs) are exact, the chart behaves
as without them, and ``softplc test --coverage`` reports what was never reached, summed
over the scenarios."""

from __future__ import annotations

import itertools
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings

from runtime.compiler.codegen import compile_grafcet
from runtime.compiler.evolution import UnstableChart
from runtime.engine.instance import Instance
from runtime.language import coverage as C
from runtime.language.grafcetfile import load_grafcet
from tests.engine.engine_reference import RefChart, Reference, Trans, Unstable
from tests.engine.enginekit import BOOT, MS
from tests.engine.test_engine_property import charts, scans
from tests.scenario.kit import cli

_serial = itertools.count()


class Counting(Reference):
    """The reference interpreter, counting what the coverage counts: each transition's
    firings, each step's activations (rule 5's re-entry and the initial situation's
    activation included), each statement action's runs."""

    def __init__(self, chart: RefChart) -> None:
        super().__init__(chart)
        self.fired = [0] * len(chart.trans)
        self.entered: Counter[str] = Counter()
        self.ran: Counter[int] = Counter()

    def apply(self, fired: list[Trans], now: int) -> tuple[set[str], set[str]]:
        for t in fired:
            self.fired[next(i for i, u in enumerate(self.c.trans) if u is t)] += 1
        out = {s for t in fired for s in t.src}
        self.entered.update(out & {s for t in fired for s in t.dst})  # rule 5
        activated, left = super().apply(fired, now)
        self.entered.update(activated)
        return activated, left

    def execute(self, a: Any) -> None:
        super().execute(a)
        self.ran[next(i for i, b in enumerate(self.c.actions) if b is a)] += 1

    def scan(self, now: int, inp: dict[str, bool], flags: dict[str, bool] | None = None
             ) -> None:
        f = flags or {}
        if not f.get("SFCInit") and (self.first or self.init_pending or (
                f.get("SFCReset") and not self.reset_prev)):
            self.entered.update(self.c.initial)  # the initial situation is activated
        super().scan(now, inp, flags)


def check_counts(tmp: Path, chart: RefChart, seq: list[Any]) -> None:
    path = tmp / f"cov{next(_serial)}.yaml"
    path.write_text(chart.yaml(), encoding="utf-8")
    inst = Instance("rnd", compile_grafcet(load_grafcet(str(path)), coverage=True))
    ref = Counting(chart)
    up = 0
    for k, (delta, inputs, flags) in enumerate(seq):
        for name, value in {**inputs, **flags}.items():
            inst.set(name, value)
        try:
            ref.scan(BOOT + up, inputs, flags)
        except Unstable:
            with pytest.raises(UnstableChart):
                inst.scan(BOOT + up, up)
            return
        inst.scan(BOOT + up, up)
        want = ref.snapshot()  # the chart behaves as without counters
        assert {key: inst.get(key) for key in want} == want, f"scan {k}\n{chart.yaml()}"
        up += delta * MS
    counts = inst.program.coverage(inst.m)
    assert [counts[f"transition:{i}"] for i in range(len(chart.trans))] == ref.fired, \
        chart.yaml()
    assert {s: counts[f"step:{s}"] for s in chart.steps} == {
        s: ref.entered[s] for s in chart.steps}, chart.yaml()
    stmts = [i for i, a in enumerate(chart.actions) if a.target is None]
    assert {i: counts[f"action:{i}"] for i in stmts} == {i: ref.ran[i] for i in stmts}, \
        chart.yaml()


SETTINGS = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])


@SETTINGS
@given(chart=charts("immediate"), seq=scans)
def test_counts_agree_with_the_reference_immediate(tmp_path: Path, chart: RefChart,
                                                   seq: list[Any]) -> None:
    check_counts(tmp_path, chart, seq)


@SETTINGS
@given(chart=charts("codesys"), seq=scans)
def test_counts_agree_with_the_reference_codesys(tmp_path: Path, chart: RefChart,
                                                 seq: list[Any]) -> None:
    check_counts(tmp_path, chart, seq)


@SETTINGS
@given(chart=charts("stable"), seq=scans)
def test_counts_agree_with_the_reference_stable(tmp_path: Path, chart: RefChart,
                                               seq: list[Any]) -> None:
    check_counts(tmp_path, chart, seq)


QUALIFIERS = """grafcet: Qualifiers
inputs: [go, a, back]
outputs: [o1, o2, o3, o4, o5, o6]
memory: {n: 0}
steps:
  s0: {initial: true}
  s1:
    actions: [o1, N o2 if a, S o3, L 20ms o4, D 30ms o5, P o6, P1 n := n + 1,
              P0 n := n + 10, N n := n + 100]
  s2: {actions: [R o3]}
transitions:
  - {from: s0, to: s1, when: go}
  - {from: s1, to: s2, when: back}
  - {from: s2, to: s0, when: 0}
"""


def test_an_action_runs_in_the_scans_where_its_part_of_the_value_is_true(
        tmp_path: Path) -> None:
    """s1 active in scans 1-5 (10 ms apart), s2 in scans 6-7: each qualifier's runs."""
    path = tmp_path / "q.yaml"
    path.write_text(QUALIFIERS, encoding="utf-8")
    g = load_grafcet(str(path))
    inst = Instance("q", compile_grafcet(g, coverage=True))
    for k in range(8):
        inst.set("go", k == 1)
        inst.set("a", k in (3, 4))
        inst.set("back", k == 6)
        inst.scan(BOOT + k * 10 * MS, k * 10 * MS)
    counts = inst.program.coverage(inst.m)
    runs = {a.text: counts[f"action:{n}"] for n, a in enumerate(g.actions())}
    assert runs == {"o1": 5, "N o2 if a": 2, "S o3": 5, "L 20ms o4": 2, "D 30ms o5": 2,
                    "P o6": 1, "P1 n := n + 1": 1, "P0 n := n + 10": 1,
                    "N n := n + 100": 5, "R o3": 2}
    assert {k: v for k, v in counts.items() if not k.startswith("action")} == {
        "step:s0": 1, "step:s1": 1, "step:s2": 1,
        "transition:0": 1, "transition:1": 1, "transition:2": 0}
    assert inst.get("n") == 1 + 10 + 500


def test_without_coverage_a_program_counts_nothing(tmp_path: Path) -> None:
    path = tmp_path / "q.yaml"
    path.write_text(QUALIFIERS, encoding="utf-8")
    g = load_grafcet(str(path))
    plain, counted = compile_grafcet(g), compile_grafcet(g, coverage=True)
    assert plain.coverage(Instance("p", plain).m) == {}
    assert "#cover:" not in plain.source and "kt0" not in plain.source
    assert len(counted.slots) == len(plain.slots) + len(g.steps) + len(g.transitions) + len(
        g.actions())


BRANCHES = """grafcet: Branches
inputs: [iGo, iLeft, iRight, iBack]
outputs: [oLeft, oRight, oBoth]
memory: {nCount: 0}
steps:
  s0: {initial: true, actions: [P1 nCount := nCount + 1]}
  sLeft: {actions: [oLeft]}
  sRight: {actions: [oRight, N oBoth if iLeft]}
  sA: {}
  sB: {}
transitions:
  - {from: s0, to: sLeft, when: iGo AND iLeft}
  - {from: s0, to: sRight, when: iGo AND iRight}
  - {from: sLeft, to: s0, when: iBack}
  - {from: sRight, to: [sA, sB], when: iBack}
  - {from: [sA, sB], to: s0, when: 1}
"""
PLANT = """plc: {cycle: 10ms}
drivers: {sim: {type: sim}}
instances:
  b:
    grafcet: branches.yaml
    inputs:
      iGo: {from: sim.I0}
      iLeft: {from: sim.I1}
      iRight: {from: sim.I2}
      iBack: {from: sim.I3}
    outputs: {oLeft: {from: sim.Q0}, oRight: {from: sim.Q1}, oBoth: {from: sim.Q2}}
"""
LEFT = """plant: plant.yaml
duration: 1s
set:
  - {at: 100ms, b.iGo: 1, b.iLeft: 1}
  - {at: 200ms, b.iGo: 0, b.iBack: 1}
expect:
  - {at: 100ms, expect: {b.sLeft.X: 1}}
  - {at: 200ms, expect: {b.s0.X: 1}}
"""
RIGHT = """plant: plant.yaml
duration: 1s
set:
  - {at: 100ms, b.iGo: 1, b.iRight: 1}
  - {at: 200ms, b.iGo: 0, b.iLeft: 1}
  - {at: 300ms, b.iBack: 1}
expect:
  - {at: 200ms, expect: {b.sRight.X: 1, b.oBoth: 1}}
  - {at: 300ms, expect: {b.sA.X: 1, b.sB.X: 1}}
  - {at: 310ms, expect: {b.s0.X: 1}}
"""


def branches(tmp_path: Path) -> Path:
    (tmp_path / "branches.yaml").write_text(BRANCHES, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(PLANT, encoding="utf-8")
    (tmp_path / "left.test.yaml").write_text(LEFT, encoding="utf-8")
    return tmp_path / "branches.yaml"


def test_a_known_untaken_branch_is_reported_exactly(tmp_path: Path) -> None:
    chart = branches(tmp_path)
    status, out = cli("test", "--coverage", str(tmp_path / "left.test.yaml"))
    assert status == 0
    lines = out.splitlines()
    start = lines.index("coverage (steps active, transitions fired, actions run, divergence "
                        "branches taken):")
    assert lines[start + 1:-1] == [
        f"  Branches ({chart}): steps 2/5, transitions 2/5, actions 2/4, branches 1/2: 42.9%",
        f"    {chart}:8:3: step sRight never active",
        f"    {chart}:9:3: step sA never active",
        f"    {chart}:10:3: step sB never active",
        f"    {chart}:13:5: transition s0 -> sRight when iGo AND iRight never fired",
        f"    {chart}:15:5: transition sRight -> sA,sB when iBack never fired",
        f"    {chart}:16:5: transition sA,sB -> s0 when 1 never fired",
        f"    {chart}:8:22: action 'oRight' of step sRight never ran",
        f"    {chart}:8:30: action 'N oBoth if iLeft' of step sRight never ran",
        f"    {chart}:13:5: branch 's0 -> sRight when iGo AND iRight' of the divergence after "
        "s0 never taken",
        "  total: 42.9% of 14 steps, transitions and actions"]


def test_coverage_is_summed_over_the_scenarios_and_gates(tmp_path: Path) -> None:
    chart = branches(tmp_path)
    status, out = cli("test", "--coverage", "--fail-under", "50", str(tmp_path))
    assert status == 1  # 42.9% < 50%
    assert "softplc test: coverage 42.9% is under --fail-under 50%" in out
    (tmp_path / "right.test.yaml").write_text(RIGHT, encoding="utf-8")
    status, out = cli("test", "--coverage", "--fail-under", "100", "-j", "2", str(tmp_path),
                      "--coverage-file", str(tmp_path / "cov.json"))
    assert status == 0, out
    assert (f"  Branches ({chart}): steps 5/5, transitions 5/5, actions 4/4, branches 2/2: "
            "100.0%") in out.splitlines()
    (cov,) = C.load(str(tmp_path / "cov.json"))
    assert cov.scenarios == 2
    counts = {(i.kind, i.key): i.count for i in cov.items}
    assert counts[("step", "s0")] == 4  # start-up and a return, in each scenario
    assert counts[("transition", "s0 -> sRight when iGo AND iRight")] == 1
    assert counts[("branch", "s0 => s0 -> sLeft when iGo AND iLeft")] == 1
    assert counts[("action", "sRight: N oBoth if iLeft")] == 10  # 200-290 ms


def test_a_coverage_file_that_is_not_one_is_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "cov.json"
    bad.write_text('{"format": "other"}', encoding="utf-8")
    with pytest.raises(C.SourceError) as exc:
        C.load(str(bad))
    assert str(exc.value) == (f"{bad}:1:1: error: not a coverage file: expected the JSON "
                              "that softplc test --coverage-file writes (format "
                              "'softplc-coverage', version 1)")
    bad.write_text("{", encoding="utf-8")
    with pytest.raises(C.SourceError, match=r":1:2: error: not a coverage file \(bad JSON"):
        C.load(str(bad))
