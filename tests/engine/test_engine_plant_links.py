"""Several charts working together (language.md; seeds 000 and 003): a parent chart starting
and stopping a child SFC through the child's SFCInit, pausing it through SFCPause, a cycle of
links, and instances of one chart owning their own state (edges included)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant

MS = 1_000_000

PARENT = """\
grafcet: Parent
inputs: [iGo, iChildDone, iHold]
outputs: [oRunChild, oPauseChild]
steps:
  p0: {initial: true}
  pRun: {actions: [oRunChild, "oPauseChild if iHold"]}
transitions:
  - {from: p0, to: pRun, when: iGo}
  - {from: pRun, to: p0, when: iChildDone}
"""

CHILD = """\
grafcet: Child
inputs: [iStep]
outputs: [oWork]
memory: {n: 0}
steps:
  c0: {initial: true, actions: ["P1 n := n + 1"]}
  c1: {actions: [oWork]}
  cEnd: {}
transitions:
  - {from: c0, to: c1, when: iStep}
  - {from: c1, to: cEnd, when: iStep}
"""

# seed 003's "SFC action": the child runs while the parent's step is active (its SFCInit is
# the inverted step flag), pauses on the parent's order; the parent waits for the child's
# last step: a cycle of links (parent <- child.cEnd.X, child <- parent.pRun.X)
PLANT = """\
plc: {cycle: 10ms}
drivers: {sim: {type: sim}}
instances:
  parent:
    grafcet: parent.yaml
    inputs: {iGo: sim.I0, iChildDone: child.cEnd.X, iHold: sim.I2}
    outputs: {oRunChild: sim.Q0, oPauseChild: sim.Q2}
  child:
    grafcet: child.yaml
    inputs:
      iStep: sim.I1
      SFCInit: {from: parent.pRun.X, invert: true}
      SFCPause: parent.oPauseChild
    outputs: {oWork: sim.Q1}
"""


@pytest.fixture
def plant(write: Callable[[str, str], str]) -> Plant:
    write("parent.yaml", PARENT)
    write("child.yaml", CHILD)
    p = Plant(load_plant(write("plant.yaml", PLANT)), sim=True)
    p.open()
    return p


def run(p: Plant, k: int, **inputs: int) -> tuple[list[str], list[str], int]:
    """Cycle ``k`` with the physical inputs given; returns (parent steps, child steps, n)."""
    p.drivers["sim"].inputs.update(inputs)
    p.cycle(k * 10 * MS)
    return (p.instances["parent"].active_steps(), p.instances["child"].active_steps(),
            p.get("child.n"))


def test_a_parent_chart_starts_and_reinitialises_a_child_through_sfcinit(plant: Plant) -> None:
    got = [run(plant, 0, I1=1)]  # the child's iStep is held true throughout
    got += [run(plant, k, I0=1) for k in range(1, 7)]
    assert got == [
        (["p0"], ["c0"], 0),  # child held by SFCInit: initial situation, no action (no P1)
        (["pRun"], ["c0"], 1),  # SFCInit falls: initial steps activated (P1), nothing fires
        (["pRun"], ["c1"], 1),
        (["pRun"], ["cEnd"], 1),
        # parent reads child.cEnd.X: the child is scanned later, so last cycle's value
        (["p0"], ["c0"], 1),  # and the child is re-initialised by the parent's step
        (["pRun"], ["c0"], 2),  # started again: a new activation of its initial step
        (["pRun"], ["c1"], 2),
    ]
    assert plant.get("child.SFCInit") is False


def test_a_parent_output_pauses_the_child(plant: Plant) -> None:
    run(plant, 0)
    run(plant, 1, I0=1)  # child started, in c0
    assert run(plant, 2, I2=1) == (["pRun"], ["c0"], 1)  # paused from this cycle on
    assert plant.get("child.SFCPause") is True
    assert run(plant, 3, I1=1) == (["pRun"], ["c0"], 1)  # iStep true: no evolution
    assert run(plant, 4, I2=0) == (["pRun"], ["c1"], 1)  # pause released: evolves at once
    assert plant.drivers["sim"].outputs["Q1"]  # oWork through the binding


def test_instances_of_one_chart_own_their_state_and_edges(
        write: Callable[[str, str], str], tmp_path: Path) -> None:
    write("edge.yaml", """\
    grafcet: Edge
    inputs: [i]
    outputs: [o]
    memory: {n: 0}
    pre: ["n := n + ↑i"]
    steps:
      s0: {initial: true}
      s1: {actions: [o]}
    transitions:
      - {from: s0, to: s1, when: ↑i}
    """)
    p = Plant(load_plant(write("plant.yaml", """\
    drivers: {sim: {type: sim}}
    instances:
      a: {grafcet: edge.yaml, inputs: {i: sim.I0}, outputs: {o: sim.Q0}}
      b: {grafcet: edge.yaml, inputs: {i: sim.I1}, outputs: {o: sim.Q1}}
    """)), sim=True)
    p.open()
    sim = p.drivers["sim"]
    p.cycle(0)
    sim.inputs["I0"] = 1
    p.cycle(10 * MS)  # a: rising edge; b: none
    assert (p.get("a.n"), p.get("b.n")) == (1, 0)
    assert (sim.outputs["Q0"], sim.outputs["Q1"]) == (True, False)
    sim.inputs["I1"] = 1
    p.cycle(20 * MS)  # b's edge, one cycle later, is its own
    assert (p.get("a.n"), p.get("b.n")) == (1, 1)
    assert (sim.outputs["Q0"], sim.outputs["Q1"]) == (True, True)
    assert p.instances["a"].program is p.instances["b"].program  # one code, two states
    assert p.instances["a"].m is not p.instances["b"].m
