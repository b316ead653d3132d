"""The scan's fast path (the body for a scan that starts with ``slow`` false, inlined in
the plant's usual cycle) against its full body, on charts that set the chart flags
themselves, in pre equations, actions and post equations, and on the features the fast
body folds around (blocks, macro-steps, max supervision, stored and timed actions), in
the three scan models: 20 instances (two groups of inlined scans) on random inputs,
every slot of every instance and every output compared after each cycle with the same
plant run on full bodies only (each instance's ``slow`` set before every cycle).

A review found two differences this test now holds: a CODESYS action setting SFCTipMode
did not stop the evolution of the same scan on the fast path, and a pre equation setting
SFCPause or SFCQuitError let the chart clock run over the paused interval (the fast path
did not record the pause)."""

from __future__ import annotations

import random
from collections.abc import Callable

import pytest

from runtime.compiler.evolution import UnstableChart
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant

CHARTS = {
    "flags_action": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
memory: {n: 0}
steps:
  s0: {initial: true, actions: ["N SFCPause := d AND a", o0]}
  s1: {actions: ["P1 SFCInit := c AND d", "L 20ms o1", "N SFCTip := b"]}
  s2: {actions: ["N SFCTipMode := c AND NOT d", "SD 10ms o0", "P0 n := n + 1"]}
transitions:
  - {from: s0, to: s1, when: a}
  - {from: s1, to: s2, when: "b OR s1.T >= 30ms"}
  - {from: s2, to: s0, when: "RE c"}
  - {from: s2, to: s1, when: "FE a"}
""",
    "tipmode_action": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
steps:
  s0: {initial: true, actions: ["N SFCTipMode := a"]}
  s1: {actions: [o0]}
transitions:
  - {from: s0, to: s1, when: a}
  - {from: s1, to: s0, when: NOT a}
post: ["o1 := b"]
""",
    "pause_pre": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
pre: ["SFCPause := b AND NOT c", "SFCQuitError := c AND d"]
steps:
  s0: {initial: true, actions: [o0]}
  s1: {actions: ["D 20ms o1"]}
transitions:
  - {from: s0, to: s1, when: "a AND s0.T >= 20ms"}
  - {from: s1, to: s0, when: "NOT a OR s1.T > 40ms"}
""",
    "flags_pre": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
memory: {n: 0}
pre: ["SFCPause := a AND b AND c", "SFCTipMode := d AND c"]
steps:
  s0: {initial: true, actions: [o0]}
  s1: {actions: ["DS 20ms o1", "N SFCTip := b"]}
transitions:
  - {from: s0, to: s1, when: a}
  - {from: s1, to: s0, when: "NOT a OR s1.T > 40ms"}
post: ["SFCReset := d AND NOT c AND b"]
""",
    "max_error": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
memory: {n: 0}
pre: ["SFCEnableLimit := NOT d"]
steps:
  s0: {initial: true}
  s1: {max: 30ms, actions: [o0]}
  s2: {max: 20ms, actions: ["SL 10ms o1"]}
transitions:
  - {from: s0, to: [s1, s2], when: a}
  - {from: [s1, s2], to: s0, when: "b AND c"}
post: ["SFCQuitError := SFCError AND d AND b", "o1 := o1 OR SFCError"]
""",
    "blocks": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
memory: {n: 0}
blocks: {ton: TON, ct: CTUD, rt: R_TRIG}
pre: ["ct(CU := a, CD := b, R := c AND d, LD := FALSE, PV := 3)", "rt(CLK := c)"]
steps:
  s0: {initial: true, actions: ["N ton(IN := a, PT := 20ms)"]}
  s1: {actions: ["D 20ms o1"]}
transitions:
  - {from: s0, to: s1, when: "ton.Q OR ct.QU"}
  - {from: s1, to: s0, when: "rt.Q OR s1.T >= 50ms"}
post: ["o0 := ton.Q OR ct.QD"]
""",
    "macro": """\
inputs: [a, b, c, d]
outputs: [o0, o1]
memory: {n: 0}
steps:
  s0: {initial: true}
  m:
    max: 40ms
    macro:
      steps:
        eA: {entry: true, actions: [o0, "P1 SFCPause := d"]}
        x: {exit: true, actions: ["L 10ms o1"]}
      transitions:
        - {from: eA, to: x, when: b}
  s9: {actions: ["N SFCInit := c AND d"]}
transitions:
  - {from: s0, to: m, when: a}
  - {from: m, to: s9, when: c}
  - {from: m, to: m, when: "FE b"}
  - {from: s9, to: s0, when: "NOT c"}
""",
}
N = 20


def plain(v: object) -> object:
    """A slot's value, a function block as the values of its fields."""
    slots = getattr(type(v), "__slots__", None)
    return tuple(getattr(v, f) for f in slots) if slots else v


def trace(path: str, seed: int, full: bool) -> list[list[object]]:
    """Every slot of every instance and every output image after each of 150 cycles, and
    the fault that ended them if one did; ``full``: every scan the full body."""
    plant = Plant(load_plant(path), sim=True, virtual=True)
    plant.open()
    sim, rnd, t = plant.drivers["sim"], random.Random(seed), 0
    out: list[list[object]] = []
    for _ in range(150):
        for i in range(8):
            sim.inputs[f"I{i}"] = int(rnd.random() < 0.4)
        if full:
            for inst in plant.instances.values():
                inst.m.slow.cell_contents = True
        try:
            plant.cycle(t)
        except UnstableChart as exc:  # the same fault at the same cycle, then stop
            out.append([str(exc)])
            break
        out.append([plain(v) for inst in plant.instances.values() for v in inst.m[:]]
                   + list(sim.outputs.values()))
        t += rnd.choice([5, 10, 10, 20]) * 1_000_000
    return out


@pytest.mark.parametrize("model", ["immediate", "codesys", "stable"])
@pytest.mark.parametrize("name", list(CHARTS))
def test_the_fast_path_gives_what_the_full_body_gives(
        write: Callable[[str, str], str], name: str, model: str) -> None:
    write("c.yaml", f"grafcet: F_{name}\nscan: {model}\n" + CHARTS[name])
    rnd = random.Random(name)
    lines = ["plc: {cycle: 10ms}", "drivers: {sim: {type: sim}}", "instances:"]
    for k in range(N):
        ins = ", ".join(f"{v}: sim.I{rnd.randrange(8)}" for v in "abcd")
        lines.append(f"  i{k}: {{grafcet: c.yaml, inputs: {{{ins}}}, "
                     f"outputs: {{o0: sim.Q{2 * k}, o1: sim.Q{2 * k + 1}}}}}")
    path = write("p.yaml", "\n".join(lines) + "\n")
    for seed in range(2):
        fast, full = trace(path, seed, False), trace(path, seed, True)
        for k, (a, b) in enumerate(zip(fast, full, strict=True)):
            assert a == b, f"seed {seed}, cycle {k}: the fast path differs"
