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


# -- the applied value: what a chart output's point holds -------------------------------
APPLIED = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  m:
    grafcet: level.yaml
    inputs: {iGo: sim.I0, iLevel: sim.IR0}
    outputs: {oRun: sim.Q0, oStop: {from: sim.Q1, invert: true}, oSpeed: sim.HR0,
              oFlow: sim.HR1}
"""
LEVEL_CHART = """\
grafcet: Level
inputs: [iGo, {iLevel: int}]
outputs: [oRun, oStop, {oSpeed: int}, {oFlow: real}]
steps:
  s0: {initial: true}
  s1: {actions: [oRun, oStop]}
transitions:
  - {from: s0, to: s1, when: iGo}
post:
  - oSpeed := iLevel + 7
  - oFlow := 2.5
"""


def test_a_chart_output_reads_what_its_point_holds(write) -> None:  # type: ignore[no-untyped-def]
    """Issue: after the safe reaction (halted, fault: every output written off) the
    displays still showed a chart output at 1 while its point held 0. Every reader of
    the Catalogue (the console's get and status, the monitor, the feed of OPC UA, MQTT
    and the page) reads a chart output as applied: its point, through the binding's
    inversion, in the output's type; the chart's own value stays readable (``chart``)."""
    from runtime.engine.names import Catalogue
    from runtime.engine.plant import Plant

    write("level.yaml", LEVEL_CHART)
    plant = Plant(load_plant(write("plant.yaml", APPLIED)), sim=True, virtual=True)
    plant.open()
    plant.set("sim.I0", 1)
    plant.set("sim.IR0", 5)
    plant.cycle(0)
    plant.cycle(10_000_000)
    cat = Catalogue(plant)
    on = {n: cat.names[f"m.{n}"].read(cat.capture(2)) for n in
          ("oRun", "oStop", "oSpeed", "oFlow")}
    assert on == {"oRun": True, "oStop": True, "oSpeed": 12, "oFlow": 2.5}
    plant.safe_state()  # the safe reaction: every point off, the charts' values kept
    img = cat.capture(3)
    shown = {n: cat.names[f"m.{n}"].read(img) for n in ("oRun", "oStop", "oSpeed", "oFlow")}
    assert shown == {"oRun": False, "oStop": True, "oSpeed": 0, "oFlow": 0.0}
    assert type(shown["oRun"]) is bool and type(shown["oFlow"]) is float
    readers = {n: cat.names[f"m.{n}"].chart for n in ("oRun", "oStop", "oSpeed", "oFlow")}
    chart = {n: r(img) for n, r in readers.items() if r is not None}
    assert chart == on  # what the chart says, not applied
    assert cat.names["sim.Q0"].read(img) == 0 and cat.names["sim.Q1"].read(img) == 0
    assert cat.names["m.iLevel"].chart is None  # inputs, memory: the chart's own value
