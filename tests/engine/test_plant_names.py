"""PlantNames: a plant's names resolved from its definition alone (no Plant built)."""

from __future__ import annotations

import pytest

from runtime.engine.names import Owner, PlantNames, UnknownName
from runtime.engine.script import read_script
from runtime.language.plantfile import load_plant

PLANT = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  first:
    grafcet: drawer.yaml
    inputs: {iParo: {from: sim.I0, invert: true}, iMarcha: sim.I1, iAbierto: sim.I2,
             iCerrado: sim.ok}
    outputs: {oAbrir: sim.Q0, oCerrar: sim.Q1, oParado: sim.Q2, oTest: sim.Q3}
"""


def names(write, drawer) -> PlantNames:  # type: ignore[no-untyped-def]
    return PlantNames(load_plant(write("plant.yaml", PLANT)))


def test_owner_of_a_name(write, drawer):  # type: ignore[no-untyped-def]
    n = names(write, drawer)
    assert n.owner("first.iMarcha") == (Owner.INSTANCE, "first", "iMarcha")
    assert n.owner("sim.Q0") == (Owner.DRIVER, "sim", "Q0")
    assert n.owner("sim.ok") == (Owner.DRIVER, "sim", "ok")
    with pytest.raises(UnknownName, match="unknown name 'sim.Q9'"):
        n.owner("sim.Q9")


def test_script_inputs(write, drawer):  # type: ignore[no-untyped-def]
    n = names(write, drawer)
    paro = n.script_input("first.iParo")
    assert (paro.driver, paro.point, paro.invert) == ("sim", "I0", True)
    flag = n.script_input("first.SFCPause")
    assert flag.driver is None and flag.instance == "first"
    assert n.script_input("first.iCerrado").bound_to == "sim.ok"
    assert n.script_input("sim.I1").point == "I1"
    with pytest.raises(UnknownName, match="did you mean 'iMarcha'"):
        n.script_input("first.iMarch")
    with pytest.raises(UnknownName, match="not an input point of driver sim"):
        n.script_input("sim.Q0")


def test_a_script_is_read_without_a_plant(write, drawer):  # type: ignore[no-untyped-def]
    n = names(write, drawer)
    path = write("s.yaml", """\
        duration: 1s
        set:
          - {at: 100ms, first.iMarcha: 1, sim.I2: 1}
          - {at: 0ms, first.iParo: 0}
        """)
    s = read_script(path, n)
    assert [(c.at_ns, c.key, c.value) for c in s.changes] == [
        (0, "first.iParo", False), (100_000_000, "first.iMarcha", True),
        (100_000_000, "sim.I2", 1)]
