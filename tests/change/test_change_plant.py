"""Plant-level state across an online change: drivers handed over untouched, forces, pause,
program time, outputs nothing drives any more, drivers to reopen."""

from __future__ import annotations

import textwrap

from runtime.change.plan import apply, prepare
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from tests.change.changekit import DRAWER_PLANT, ROOT, Story, data_plant, sim_plant, state, version

CHART = str(ROOT / "configs/drawer_tester/drawer_tester.yaml")


def drawer_text() -> str:
    return (ROOT / "configs/drawer_tester/plant_sim.yaml").read_text().replace(
        "grafcet: drawer_tester.yaml", f"grafcet: {CHART}")


def opening() -> Story:
    """tester1 in gsAbrir (oAbrir on, sim.Q0 = 1) at 600 ms."""
    story = Story(sim_plant(DRAWER_PLANT))
    story.run(60)
    assert story.plant.drivers["sim"].outputs["Q0"] == 1
    return story


def test_prepare_leaves_the_running_drivers_alone():
    """The new plant is built on the running sim driver object; building it must not
    declare the points again (that zeroes the images the running scan reads and writes)."""
    story = opening()
    old = story.plant
    d = old.drivers["sim"]
    images = (dict(d.inputs), dict(d.outputs))
    prep = prepare(old, version(data_plant("timeout"), old))
    assert prep.plant.drivers["sim"] is d
    assert (dict(d.inputs), dict(d.outputs)) == images


def test_forces_pause_and_program_time_carry_and_a_force_on_a_gone_name_is_released(tmp_path):
    story = opening()
    old = story.plant
    old.force("tester1.oTest", 0)
    old.force("tester2.sParo", 1)
    old.force("sim.Q5", 1)
    old.pause()
    old.cycle(60 * 10_000_000 + 5_000_000)  # held: the charts' time stands still
    src = open(CHART).read().replace("sParo", "sStop")
    (tmp_path / "c.yaml").write_text(src)
    (tmp_path / "p.yaml").write_text(drawer_text().replace(CHART, str(tmp_path / "c.yaml")))
    prep = prepare(old, version(str(tmp_path / "p.yaml"), old))
    res = apply(old, prep)
    assert res.refusals == []
    new = prep.plant
    assert new.forced_values() == {"tester1.oTest": False, "sim.Q5": 1}
    assert "force tester2.sParo released: no longer in the plant" in res.lines
    assert new.held and new.scans == old.scans and new.start == old.start
    assert (new.offset_ns, new.last_up) == (old.offset_ns, old.last_up)
    # resumed, the next scan comes one cycle after the last, as it would have
    new.resume()
    new.cycle(10**10)
    assert new.instances["tester1"].step_time("gsAbrir") == 100_000_000
    assert new.drivers["sim"].outputs["Q3"] == 0  # oTest forced off
    assert new.drivers["sim"].outputs["Q5"] == 1


def test_an_output_nothing_drives_any_more_goes_off(tmp_path):
    """The edit makes oAbrir a memory variable of the chart (its bindings go): the points
    it drove, sim.Q0 on at 600 ms, go off; the others keep what the chart decides."""
    story = opening()
    old = story.plant
    src = open(CHART).read().replace("outputs: [oAbrir, ", "outputs: [").replace(
        "memory:\n", "memory:\n  oAbrir: false\n")
    (tmp_path / "c.yaml").write_text(src)
    text = drawer_text().replace(CHART, str(tmp_path / "c.yaml"))
    text = "".join(line for line in text.splitlines(keepends=True)
                   if not line.startswith("      oAbrir:"))
    (tmp_path / "p.yaml").write_text(text)
    prep = prepare(old, version(str(tmp_path / "p.yaml"), old))
    res = apply(old, prep)
    assert res.refusals == []
    assert res.lines[-2:] == ["sim.Q0: no longer driven: off", "sim.Q4: no longer driven: off"]
    new = prep.plant
    assert new.drivers["sim"].outputs["Q0"] == 0
    story.bind(new)
    row = story.run(1)[0]
    assert (row["sim.Q0"], row["sim.Q3"], row["tester1.oAbrir"]) == (0, 1, True)


def test_an_instance_removed_leaves_its_outputs_off(tmp_path):
    story = Story(sim_plant(DRAWER_PLANT))
    story.run(120)  # tester2 in gsAbrir from 1000 ms: sim.Q4 on
    old = story.plant
    assert old.drivers["sim"].outputs["Q4"] == 1
    text = drawer_text()
    text = text[:text.index("  tester2:")] + text[text.index("monitor:"):]
    (tmp_path / "p.yaml").write_text(text)
    prep = prepare(old, version(str(tmp_path / "p.yaml"), old))
    res = apply(old, prep)
    assert res.refusals == []
    assert "tester2: instance removed (its outputs go off)" in res.lines
    assert "sim.Q4: no longer driven: off" in res.lines
    new = prep.plant
    new.cycle(120 * 10_000_000)
    assert new.drivers["sim"].outputs["Q4"] == 0
    assert new.drivers["sim"].outputs["Q0"] == old.drivers["sim"].outputs["Q0"]


def test_a_changed_driver_is_refused_then_reopened_when_forced(tmp_path):
    text = textwrap.dedent(f"""\
        drivers:
          sim: {{type: sim}}
          io: {{type: sim, on_fault: stop}}
        instances:
          t:
            grafcet: {CHART}
            inputs: {{iParo: sim.I0, iMarcha: sim.I1, iAbierto: sim.I2, iCerrado: io.I3}}
            outputs: {{oAbrir: sim.Q0, oCerrar: sim.Q1, oParado: sim.Q2, oTest: io.Q3}}
        """)
    (tmp_path / "a.yaml").write_text(text)
    (tmp_path / "b.yaml").write_text(text.replace("on_fault: stop", "on_fault: hold"))
    old = Plant(load_plant(str(tmp_path / "a.yaml")), sim=True, virtual=True)
    old.open()
    old.cycle(0)
    before = state(old)
    prep = prepare(old, version(str(tmp_path / "b.yaml"), old))
    res = apply(old, prep)
    assert res.refusals == ["driver io: on_fault changed: the bus must be reopened"]
    assert state(old) == before
    res = apply(old, prep, force=True)
    assert res.refusals == []
    assert res.reopened == ["io"] and res.closed == ["io"]
    assert prep.plant.drivers["io"] is not old.drivers["io"]
    assert prep.plant.drivers["sim"] is old.drivers["sim"]


def test_a_scan_model_change_waits_for_a_pending_evolution(tmp_path):
    src = open(CHART).read()
    (tmp_path / "cs.yaml").write_text(src.replace("scan: immediate", "scan: codesys"))
    (tmp_path / "a.yaml").write_text(drawer_text().replace(CHART, str(tmp_path / "cs.yaml")))
    old = Plant(load_plant(str(tmp_path / "a.yaml")), sim=True, virtual=True)
    old.open()
    old.set("sim.I0", 1)
    old.set("sim.I4", 1)
    old.cycle(0)
    old.set("sim.I1", 1)
    old.cycle(10_000_000)  # decides gsParado -> gsAbrir for the next scan
    prep = prepare(old, version(DRAWER_PLANT, old))
    assert prep.changes.state_checks() == [
        "tester1: refused while an evolution is pending (scan model codesys -> immediate)",
        "tester2: refused while an evolution is pending (scan model codesys -> immediate)"]
    res = apply(old, prep)
    assert res.refusals == ["tester1: the pending evolution gsParado->gsAbrir would be lost"]
    old.cycle(20_000_000)
    assert old.instances["tester1"].active_steps() == ["gsAbrir"]
    res = apply(old, prep)
    assert res.refusals == []
    assert "tester1: scan model codesys -> immediate" in res.lines


def test_a_flag_pulse_asked_for_before_the_swap_runs_in_the_swap_scan():
    story = opening()
    old = story.plant
    old.pulse("tester1", "SFCInit")
    prep = prepare(old, version(data_plant("timeout"), old))
    assert apply(old, prep).refusals == []
    story.bind(prep.plant)
    row = story.run(1)[0]
    assert row["tester1.gsParado.X"] and not row["tester1.gsAbrir.X"]
    assert row["sim.Q0"] == 0


LEVELS = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  a:
    grafcet: level.yaml
    inputs: {iOn: sim.I0, iLevel: sim.level}
    outputs: {oHigh: sim.Q0}
  c:
    grafcet: level.yaml
    inputs: {iOn: sim.I1, iLevel: sim.level}
    outputs: {oHigh: sim.Q1}
"""


def test_the_input_bits_change_with_the_swap_not_before(tmp_path, level):
    """``sim.I0`` is a bit (a bool, read as it is) while only ``a.iOn`` reads it; the
    change has ``c.iLevel`` read it as a number too. Preparing leaves the running image's
    bits alone (the running cycle reads ``I0`` as it is); the swap makes it a number."""
    (tmp_path / "p.yaml").write_text(LEVELS)
    (tmp_path / "q.yaml").write_text(LEVELS.replace(
        "{iOn: sim.I1, iLevel: sim.level}", "{iOn: sim.I1, iLevel: sim.I0}"))
    old = sim_plant(str(tmp_path / "p.yaml"))
    d = old.drivers["sim"]
    i0, i1 = d.inputs.index["I0"], d.inputs.index["I1"]
    assert d.inputs.bits == old.bits["sim"] == {i0, i1}
    d.inputs["I0"] = 5
    assert d.inputs["I0"] is True
    old.cycle(0)
    prep = prepare(old, version(str(tmp_path / "q.yaml"), old))
    assert prep.plant.drivers["sim"] is d
    assert prep.plant.bits["sim"] == {i1} and d.inputs.bits == {i0, i1}
    assert apply(old, prep).refusals == []
    assert d.inputs.bits == {i1}
    assert d.inputs["I0"] == 1 and type(d.inputs["I0"]) is int  # no bit: 0 or 1 again
    prep.plant.cycle(5_000_000)
    assert prep.plant.get("c.iLevel") == 1 and type(prep.plant.get("c.iLevel")) is int
    d.inputs["I0"] = 5
    d.inputs["I1"] = 1
    prep.plant.cycle(10_000_000)
    assert prep.plant.get("c.iLevel") == 5 and prep.plant.get("a.iOn") is True
    assert d.inputs["I0"] == 5 and d.inputs["I1"] is True
