"""What apply refuses, with its one line each, and what a refusal leaves: nothing changed."""

from __future__ import annotations

from runtime.change.plan import apply, prepare
from tests.change.changekit import DRAWER_PLANT, Story, data_plant, sim_plant, state, version


def story_at(k: int) -> Story:
    story = Story(sim_plant(DRAWER_PLANT))
    story.run(k)
    return story


def test_a_retained_type_change_is_refused_even_forced():
    story = story_at(100)
    old = story.plant
    before = state(old)
    prep = prepare(old, version(data_plant("retained_type"), old))
    for force in (False, True):
        res = apply(old, prep, force=force)
        assert res.refusals == ["tester1: retained variable sCierres changes type int -> real",
                                "tester2: retained variable sCierres changes type int -> real"]
        assert res.lines == [] and res.restarted == [] and res.reopened == []
    assert state(old) == before
    # and the old plant runs on as if nothing happened
    rows = story.run(10)
    assert rows[-1]["tester1.gsAbrir.X"] == (old.instances["tester1"].active_steps() == ["gsAbrir"])


def removed_active_step(tmp_path):
    """The drawer chart with gsAbrir renamed without ``renamed_from``: the old gsAbrir is
    removed, and it is active in tester1 at 600 ms."""
    from tests.change.changekit import ROOT
    src = (ROOT / "configs/drawer_tester/drawer_tester.yaml").read_text()
    (tmp_path / "chart.yaml").write_text(src.replace("gsAbrir", "gsOpen"))
    plant = (ROOT / "configs/drawer_tester/plant_sim.yaml").read_text()
    (tmp_path / "plant.yaml").write_text(plant.replace("drawer_tester.yaml", "chart.yaml"))
    return str(tmp_path / "plant.yaml")


def test_an_active_step_removed_is_refused_and_restart_restarts_that_instance_only(tmp_path):
    path = removed_active_step(tmp_path)
    story = story_at(60)
    old = story.plant
    assert old.instances["tester1"].active_steps() == ["gsAbrir"]
    assert old.instances["tester2"].active_steps() == ["gsParado"]
    before = state(old)
    prep = prepare(old, version(path, old))
    res = apply(old, prep)
    assert res.refusals == ["tester1: step gsAbrir removed while it is active "
                            "(--restart tester1 restarts that instance)"]
    assert state(old) == before
    assert state(prep.plant) == state(sim_plant(path))  # the new plant untouched too
    res = apply(old, prep, restart=["tester1"])
    assert res.refusals == [] and res.restarted == ["tester1"]
    new = prep.plant
    assert new.instances["tester1"].active_steps() == ["gsParado"]
    assert new.instances["tester2"].active_steps() == ["gsParado"]
    assert new.instances["tester2"].m[new.instances["tester2"].program.var_index("sParo")] \
        == old.instances["tester2"].m[old.instances["tester2"].program.var_index("sParo")]


def test_a_rename_with_renamed_from_carries_the_active_step(tmp_path):
    from tests.change.changekit import ROOT
    src = (ROOT / "configs/drawer_tester/drawer_tester.yaml").read_text()
    src = src.replace("gsAbrir", "gsOpen").replace(
        "  gsOpen:\n    description: Opening the drawer\n",
        "  gsOpen:\n    renamed_from: gsAbrir\n    description: Opening the drawer\n")
    (tmp_path / "chart.yaml").write_text(src)
    plant = (ROOT / "configs/drawer_tester/plant_sim.yaml").read_text()
    (tmp_path / "plant.yaml").write_text(plant.replace("drawer_tester.yaml", "chart.yaml"))
    story = story_at(60)
    old = story.plant
    t_before = old.instances["tester1"].step_time("gsAbrir")
    prep = prepare(old, version(str(tmp_path / "plant.yaml"), old))
    assert "tester1: step gsOpen renamed from gsAbrir" in prep.changes.lines()
    res = apply(old, prep)
    assert res.refusals == []
    new = prep.plant.instances["tester1"]
    assert new.active_steps() == ["gsOpen"]
    assert new.step_time("gsOpen") == t_before == 90_000_000  # from 500 ms to 590 ms


def test_apply_twice_is_refused():
    story = story_at(10)
    prep = prepare(story.plant, version(data_plant("timeout"), story.plant))
    assert apply(story.plant, prep).refusals == []
    assert apply(story.plant, prep).refusals == ["this change was applied already: prepare "
                                                 "it again"]


def test_forced_an_active_step_removed_is_dropped_and_said(tmp_path):
    path = removed_active_step(tmp_path)
    story = story_at(60)
    prep = prepare(story.plant, version(path, story.plant))
    res = apply(story.plant, prep, force=True)
    assert res.refusals == []
    assert "tester1: active step gsAbrir dropped (forced)" in res.lines
    assert prep.plant.instances["tester1"].active_steps() == []
    assert prep.plant.instances["tester2"].active_steps() == ["gsParado"]
    # tester1, left without an active step, is in fault: not scanned, its outputs off;
    # tester2 runs on (the story starts it)
    assert res.instance_faults == {"tester1": "no active step left (the forced change "
                                              "dropped gsAbrir)"}
    new = prep.plant
    story.bind(new)
    rows = story.run(400)
    points = [f"{b.driver}.{b.point}" for b in new.pdef.instances["tester1"].outputs.values()]
    assert all(row[p] == 0 for row in rows for p in points)
    assert all(not row[f"tester1.{s}.X"] for row in rows for s in ("gsParado", "gsOpen"))
    assert any(row["tester2.gsCerrar.X"] for row in rows)
    new.restart_instance("tester1")  # what ack and reload --restart do
    assert new.instances["tester1"].active_steps() == ["gsParado"] and not new.instance_faults


def test_a_chart_that_empties_its_situation_itself_is_no_fault(tmp_path):
    """A sink transition may leave a chart with no active step (SFCReset brings it back):
    a change that drops no active step leaves it as it is, scanned."""
    chart = ("grafcet: Sink\ninputs: [iGo]\noutputs: [oRun]\nsteps:\n"
             "  s0: {initial: true, actions: [oRun]}\ntransitions:\n"
             "  - {from: s0, to: [], when: iGo}\n")
    (tmp_path / "sink.yaml").write_text(chart)
    (tmp_path / "plant.yaml").write_text(
        "drivers:\n  sim: {type: sim}\ninstances:\n  m:\n    grafcet: sink.yaml\n"
        "    inputs: {iGo: sim.I0}\n    outputs: {oRun: sim.Q0}\n")
    old = sim_plant(str(tmp_path / "plant.yaml"))
    old.drivers["sim"].inputs["I0"] = 1
    old.cycle(0)
    old.cycle(10_000_000)
    assert old.instances["m"].active_steps() == []
    (tmp_path / "sink.yaml").write_text(chart.replace("when: iGo", "when: iGo AND TRUE"))
    prep = prepare(old, version(str(tmp_path / "plant.yaml"), old))
    res = apply(old, prep, force=True)
    assert res.refusals == [] and res.instance_faults == {} and not prep.plant.instance_faults


def test_restart_of_an_unknown_instance_is_refused():
    story = story_at(10)
    prep = prepare(story.plant, version(data_plant("timeout"), story.plant))
    assert apply(story.plant, prep, restart=["tester9"]).refusals == [
        "--restart tester9: no such instance in the new plant"]


def test_a_new_initial_step_starts_inactive(tmp_path):
    """Only a fresh start activates the initial steps: an initial step the change adds to
    a running chart starts inactive (docs: a new step starts inactive), never active beside
    the situation the machine is in."""
    from tests.change.changekit import ROOT
    src = (ROOT / "configs/drawer_tester/drawer_tester.yaml").read_text()
    (tmp_path / "chart.yaml").write_text(src.replace(
        "  gsAbrir:\n", "  gsExtra: {initial: true}\n  gsAbrir:\n").replace(
        "transitions:\n", "transitions:\n  - {from: gsExtra, to: gsParado, when: iParo}\n"))
    plant = (ROOT / "configs/drawer_tester/plant_sim.yaml").read_text()
    (tmp_path / "plant.yaml").write_text(plant.replace("drawer_tester.yaml", "chart.yaml"))
    story = story_at(60)
    prep = prepare(story.plant, version(str(tmp_path / "plant.yaml"), story.plant))
    res = apply(story.plant, prep)
    assert res.refusals == [] and "tester1: step gsExtra added" in res.lines
    assert prep.plant.instances["tester1"].active_steps() == ["gsAbrir"]
    assert prep.plant.instances["tester2"].active_steps() == ["gsParado"]
