"""The plant's generated cycles: the fast one keeps each instance's outputs apart whatever
the instance and variable names, and the usual cycle takes the fast path."""

from __future__ import annotations

from collections.abc import Callable

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
