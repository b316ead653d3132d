"""The plant: bindings, inversion at the binding, links between instances, forces."""

from __future__ import annotations

from drivers.sim import SimDriver
from runtime.engine.plant import BindingError, Plant
from runtime.language.plantfile import load_plant

MS = 1_000_000

TWO = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  first:
    grafcet: drawer.yaml
    inputs:
      iParo: {from: sim.I0, invert: true}
      iMarcha: sim.I1
      iAbierto: sim.I2
      iCerrado: sim.I3
    outputs: {oAbrir: sim.Q0, oCerrar: sim.Q1, oParado: sim.Q2, oTest: sim.Q3}
  second:
    grafcet: drawer.yaml
    inputs:
      iParo: {from: first.gsAbrir.X, invert: true}
      iMarcha: first.oAbrir
      iAbierto: third.oTest
      iCerrado: sim.I13
      SFCPause: sim.I14
    outputs: {oAbrir: sim.Q10, oCerrar: sim.Q11, oParado: sim.Q12, oTest: sim.Q13}
  third:
    grafcet: drawer.yaml
    inputs:
      iParo: {from: sim.I20, invert: true}
      iMarcha: first.oAbrir
      iAbierto: sim.I22
      iCerrado: sim.I23
    outputs: {oAbrir: sim.Q20, oCerrar: sim.Q21, oParado: sim.Q22, oTest: sim.Q23}
"""


def make(write, drawer):  # type: ignore[no-untyped-def]
    plant = Plant(load_plant(write("plant.yaml", TWO)), sim=True)
    plant.open()
    sim = plant.drivers["sim"]
    sim.inputs.update({"I0": 1, "I20": 1})  # NC stop buttons closed: no stop order
    return plant, sim


def test_invert_happens_at_the_binding(write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.cycle(0)
    assert plant.get("first.iParo") is False  # NC contact closed (1) -> no stop order
    sim.inputs["I0"] = 0  # pressed: the NC contact opens
    plant.cycle(10 * MS)
    assert plant.get("first.iParo") is True
    assert plant.get("first.sParo") is True


def test_links_read_this_cycle_from_earlier_instances_and_last_cycle_from_later(
        write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.cycle(0)
    sim.inputs["I1"] = 1  # start 'first'
    plant.cycle(10 * MS)
    assert plant.get("first.oAbrir") is True
    # 'second' and 'third' are scanned after 'first': they see this cycle's oAbrir
    assert plant.get("second.iMarcha") is True
    assert plant.get("third.iMarcha") is True
    assert plant.instances["second"].active_steps() == ["gsAbrir"]
    assert plant.get("third.oTest") is True
    # 'second' reads third.oTest, scanned later: the previous cycle's value (false)
    assert plant.get("second.iAbierto") is False
    plant.cycle(20 * MS)
    assert plant.get("second.iAbierto") is True
    assert plant.instances["second"].active_steps() == ["gsCerrar"]


def test_before_its_first_scan_an_instance_shows_its_initial_situation(
        write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    # 'second' reads first.gsAbrir.X before any scan: initial situation, step inactive
    assert plant.get("first.gsParado.X") is True
    assert plant.get("first.oAbrir") is False
    plant.cycle(0)
    assert plant.get("second.iParo") is True  # inverted gsAbrir.X = 0


def test_chart_flag_bound_to_a_point(write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.cycle(0)
    sim.inputs["I14"] = 1
    sim.inputs["I1"] = 1
    plant.cycle(10 * MS)
    assert plant.get("second.SFCPause") is True
    assert plant.instances["second"].active_steps() == ["gsParado"]  # paused: no evolution


def test_outputs_reach_the_driver_image(write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.cycle(0)
    assert sim.outputs["Q2"] is True  # oParado
    sim.inputs["I1"] = 1
    plant.cycle(10 * MS)
    assert (sim.outputs["Q0"], sim.outputs["Q2"], sim.outputs["Q3"]) == (True, False, True)
    plant.safe_state()
    assert not any(sim.outputs.values())


def test_forces_win_over_drivers_and_program(write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.cycle(0)
    plant.force("first.oParado", 0)  # the program drives it true in gsParado
    plant.force("sim.I2", 1)  # physical input
    plant.cycle(10 * MS)
    assert sim.outputs["Q2"] is False
    assert plant.get("first.iAbierto") is True
    sim.inputs["I2"] = 0  # the driver says 0: the force still wins
    plant.cycle(20 * MS)
    assert plant.get("first.iAbierto") is True
    plant.unforce()
    plant.cycle(30 * MS)
    assert sim.outputs["Q2"] is True
    assert plant.get("first.iAbierto") is False


def test_unknown_names_are_refused(write, drawer):  # type: ignore[no-untyped-def]
    plant, _ = make(write, drawer)
    for bad in ("nobody.x", "first.nothing", "sim.Q99"):
        try:
            plant.force(bad, 1)
        except BindingError:
            continue
        raise AssertionError(f"{bad} accepted")


def test_retain_snapshot_and_restart(write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.instances["first"].set("sCierres", 41)
    snap = plant.retain_snapshot()
    assert snap["first"] == {"sCierres": 41}
    plant.cycle(0)
    sim.inputs["I1"] = 1
    plant.cycle(10 * MS)
    plant.restart()
    assert plant.instances["first"].active_steps() == ["gsParado"]
    assert plant.get("first.sCierres") == 41
    plant.restore_retain({"first": {"sCierres": 7, "unknown": 1}})
    assert plant.get("first.sCierres") == 7


def test_hold_scans_io_but_not_charts_and_step_lets_n_cycles_through(write, drawer):  # type: ignore
    plant, sim = make(write, drawer)
    plant.cycle(0)
    plant.hold = True
    sim.inputs["I1"] = 1
    plant.cycle(10 * MS)
    assert plant.get("first.gsParado.X") is True  # not scanned
    plant.step(1)
    plant.cycle(20 * MS)
    assert plant.get("first.gsAbrir.X") is True
    sim.inputs["I2"] = 1
    plant.cycle(30 * MS)
    assert plant.get("first.gsAbrir.X") is True  # held again after one cycle


def test_pulse_init_for_one_scan(write, drawer):  # type: ignore[no-untyped-def]
    plant, sim = make(write, drawer)
    plant.cycle(0)
    sim.inputs["I1"] = 1
    plant.cycle(10 * MS)
    assert plant.get("first.gsAbrir.X") is True
    plant.pulse("first", "SFCInit")
    plant.cycle(20 * MS)
    assert plant.get("first.gsParado.X") is True  # SFCInit held true for that scan
    assert plant.get("first.oAbrir") is False and plant.get("first.SFCInit") is False
    plant.cycle(30 * MS)  # SFCInit fell: initial steps activated, start still held: no edge
    assert plant.instances["first"].active_steps() == ["gsParado"]


def test_iocheck_stops_charts_and_leaves_outputs_to_the_technician(write, drawer):  # type: ignore
    plant, sim = make(write, drawer)
    plant.cycle(0)
    assert sim.outputs["Q2"] is True
    plant.set_iocheck(True)
    assert not any(sim.outputs.values())
    plant.set("sim.Q1", 1)
    sim.inputs["I1"] = 1
    plant.cycle(10 * MS)
    assert sim.outputs["Q1"] == 1 and plant.get("first.gsParado.X") is True
    plant.set_iocheck(False)
    assert not any(sim.outputs.values())


SHARED = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  a:
    grafcet: level.yaml
    inputs: {iOn: sim.I0, iLevel: sim.level}
    outputs: {oHigh: sim.Q1}
  b:
    grafcet: level.yaml
    inputs: {iOn: {from: sim.I1, invert: true}, iLevel: sim.I0}
    outputs: {oHigh: sim.Q0}
"""


def test_only_points_read_as_bool_alone_are_bits(write, level):  # type: ignore[no-untyped-def]
    """A bit of an input image holds a bool, read by the cycle as it is. A point some
    instance reads as a number (``sim.I0``, BOOL by its name, read as ``b.iLevel``) or a
    sim point read as a number whatever its name (``sim.level``) is not one: its values
    stay numbers, and its BOOL binding converts (``a.iOn``)."""
    plant = Plant(load_plant(write("plant.yaml", SHARED)), sim=True)
    plant.open()
    sim = plant.drivers["sim"]
    assert sim.inputs.bits == plant.bits["sim"] == {sim.inputs.index["I1"]}
    sim.inputs["I0"] = 5
    sim.inputs["level"] = 7
    sim.inputs["I1"] = 0  # inverted: b.iOn TRUE
    plant.cycle(0)
    assert sim.inputs["I0"] == 5 and sim.inputs["level"] == 7
    assert plant.get("a.iOn") is True and plant.get("a.iLevel") == 7
    assert plant.get("b.iOn") is True and plant.get("b.iLevel") == 5
    assert type(sim.inputs["I1"]) is bool
    plant.cycle(10 * MS)
    assert plant.get("a.s1.X") is True and plant.get("b.s1.X") is True
    assert sim.outputs["Q0"] is True
    sim.inputs["I1"] = 1
    sim.inputs["I0"] = 2
    plant.cycle(20 * MS)
    assert plant.get("b.iOn") is False and plant.get("b.iLevel") == 2
    assert plant.get("b.s1.X") is False and plant.get("a.iOn") is True
    sim.inputs["level"] = True  # a bool at a BOOL point: a number variable reads 1
    plant.cycle(30 * MS)
    assert plant.get("a.iLevel") == 1 and type(plant.get("a.iLevel")) is int


def test_drivers_handed_to_a_new_plant_get_its_bits(write, level):  # type: ignore[no-untyped-def]
    """A plant built on drivers made elsewhere (``drivers=``: a daemon's, a test's)
    declares its bits on them at once; only an online change waits for the swap."""
    sim = SimDriver("sim")
    plant = Plant(load_plant(write("plant.yaml", SHARED)), drivers={"sim": sim})
    assert sim.inputs.bits == plant.bits["sim"] == {sim.inputs.index["I1"]}
    plant.open()
    sim.set_input("I1", 0)
    plant.force("sim.I1", 1)
    plant.cycle(0)
    assert plant.get("b.iOn") is False  # forced 1, inverted: a bool, not 0
    assert sim.inputs["I1"] is False  # the physical value back after the scan
