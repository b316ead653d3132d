"""The plant's generated cycles: the fast one keeps each instance's outputs apart whatever
the instance and variable names, and the usual cycle takes the fast path."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant

ON = """\
grafcet: On
inputs: [i]
outputs: [c]
steps:
  s0: {initial: true, actions: [c]}
"""

OFF = """\
grafcet: Off
inputs: [i]
outputs: [b_c]
steps:
  s0: {initial: true}
"""

# "a_b" . "c" and "a" . "b_c": the same text once joined by "_"
PLANT = """\
plc: {cycle: 10ms}
drivers: {sim: {type: sim}}
instances:
  a_b:
    grafcet: on.yaml
    inputs: {i: sim.I0}
    outputs: {c: sim.Q0}
  a:
    grafcet: off.yaml
    inputs: {i: sim.I1}
    outputs: {b_c: sim.Q1}
"""


def test_outputs_of_instances_whose_names_join_alike_stay_apart(
        write: Callable[[str, str], str]) -> None:
    write("on.yaml", ON)
    write("off.yaml", OFF)
    plant = Plant(load_plant(write("plant.yaml", PLANT)), sim=True)
    plant.open()
    for k in range(3):
        assert plant.cycle(k * 10_000_000) is None
    out = plant.drivers["sim"].outputs
    assert (out["Q0"], out["Q1"]) == (1, 0)
    assert "cycle_slow" in plant.source and plant.scans == 3


SELF = """\
grafcet: Self
inputs: [stop, go]
outputs: [run]
steps:
  s0: {initial: true}
  s1: {actions: [run]}
transitions:
  - {from: s0, to: s1, when: go}
  - {from: s1, to: s0, when: NOT go}
"""


@pytest.mark.parametrize("inputs", ["{stop: sim.I0, SFCPause: A.stop, go: sim.I1}",
                                    "{SFCPause: A.stop, stop: sim.I0, go: sim.I1}"])
def test_a_flag_bound_to_its_own_input_sees_this_cycles_value_in_both_cycles(
        write: Callable[[str, str], str], inputs: str) -> None:
    """SFCPause bound to the instance's own bound input: the fast cycle read the input of
    the previous cycle (the inputs reach the state inside the scan), the slow cycle this
    cycle's or the previous one's depending on the file's order (a review found both)."""
    write("c.yaml", SELF)
    path = write("p.yaml", "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\n"
                 f"instances:\n  A:\n    grafcet: c.yaml\n    inputs: {inputs}\n"
                 "    outputs: {run: sim.Q0}\n")

    def run(fast: bool) -> list[tuple[int, int, bool, int]]:
        pl = Plant(load_plant(path), sim=True, virtual=True)
        pl.open()
        sim, out = pl.drivers["sim"], []
        for k, (stop, go) in enumerate([(0, 0), (0, 0), (1, 1), (1, 1), (0, 1), (0, 1)]):
            sim.inputs["I0"], sim.inputs["I1"] = stop, go
            (pl._cycle_fast if fast else pl._cycle)(k * 10_000_000, k * 10_000_000)
            out.append((stop, go, pl.instances["A"].get("SFCPause"), sim.outputs["Q0"]))
        return out
    # paused in the very cycle the stop comes: the chart does not start `run`
    expected = [(0, 0, False, 0), (0, 0, False, 0), (1, 1, True, 0), (1, 1, True, 0),
                (0, 1, False, 1), (0, 1, False, 1)]
    assert run(True) == expected
    assert run(False) == expected
