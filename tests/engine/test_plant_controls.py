"""The plant's methods for the console and the daemon: pause/resume/step, forces."""

from __future__ import annotations

from runtime.engine.plant import ForcedPoint, ForcedVariable, Plant
from runtime.language.plantfile import load_plant

MS = 1_000_000

ONE = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  first:
    grafcet: drawer.yaml
    inputs: {iParo: sim.I0, iMarcha: sim.I1, iAbierto: sim.I2, iCerrado: sim.I3}
    outputs: {oAbrir: sim.Q0, oCerrar: sim.Q1, oParado: sim.Q2, oTest: sim.Q3}
"""


def make(write, drawer) -> Plant:  # type: ignore[no-untyped-def]
    plant = Plant(load_plant(write("plant.yaml", ONE)), sim=True)
    plant.open()
    return plant


def test_pause_resume_and_step(write, drawer):  # type: ignore[no-untyped-def]
    plant = make(write, drawer)
    assert not plant.held and not plant.stepping
    assert plant.pause() is False and plant.held
    assert plant.pause() is True
    plant.step(2)
    assert plant.stepping
    plant.cycle(0)
    plant.cycle(10 * MS)
    assert not plant.stepping and plant.held
    assert plant.resume() is True and not plant.held
    assert plant.resume() is False


def test_forces_are_listed_as_records(write, drawer):  # type: ignore[no-untyped-def]
    plant = make(write, drawer)
    plant.force("first.iMarcha", 1)
    plant.force("sim.Q0", 1)
    assert plant.is_forced("first.iMarcha") and plant.is_forced("sim.Q0")
    assert not plant.is_forced("first.iParo")
    assert plant.forced_names() == ["first.iMarcha", "sim.Q0"]
    assert plant.forced_values() == {"first.iMarcha": True, "sim.Q0": 1}
    var = plant.forced["first.iMarcha"]
    assert isinstance(var, ForcedVariable) and var.instance == "first" and var.value is True
    assert var.slot == plant.instances["first"].program.var_index("iMarcha")
    point = plant.forced_points["sim.Q0"]
    assert isinstance(point, ForcedPoint) and point.is_output and point.point == "Q0"
    plant.unforce(None)
    assert plant.forced_names() == []
