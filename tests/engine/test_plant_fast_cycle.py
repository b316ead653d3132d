"""The plant's generated cycles: the fast one keeps each instance's outputs apart whatever
the instance and variable names, the usual cycle takes the fast path, and the scans it
inlines (runtime/engine/inline.py) work on the instances' own state and name the instance
of a fault."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from drivers.sim import SimDriver
from runtime.compiler.emit import renamed
from runtime.engine import inline
from runtime.engine.plant import Plant
from runtime.engine.simulate import ScanFault, Simulation
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
            t = k * 10_000_000
            pl._cycle_fast((t, t)) if fast else pl._cycle(t, t)
            out.append((stop, go, pl.instances["A"].get("SFCPause"), sim.outputs["Q0"]))
        return out
    # paused in the very cycle the stop comes: the chart does not start `run`
    expected = [(0, 0, False, 0), (0, 0, False, 0), (1, 1, True, 0), (1, 1, True, 0),
                (0, 1, False, 1), (0, 1, False, 1)]
    assert run(True) == expected
    assert run(False) == expected


DIVIDES = """\
grafcet: U
inputs: [d]
memory: {q: 0}
pre: ["q := 10 / (1 - d)"]
steps:
  s: {initial: true}
"""


def test_a_fault_in_an_inlined_scan_names_its_instance(
        write: Callable[[str, str], str]) -> None:
    """The usual cycle runs the instances' scans inlined in its own functions: a fault
    there (a division by zero driven by a physical input, in a fast scan) is still
    reported at the instance whose scan raised, not at the first of the plant."""
    write("u.yaml", DIVIDES)
    plant = write("p.yaml", "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\n"
                  "instances:\n" + "".join(f"  u{k}: {{grafcet: u.yaml, inputs: {{d: sim.I{k}}}}}\n"
                                           for k in range(20)))
    script = write("s.yaml", "cycles: 10\nset:\n  - {at: 30ms, sim.I17: 1}\n")
    sim = Simulation(plant, script)
    with pytest.raises(ScanFault) as err:
        for _ in sim.run(trace=False):
            pass
    assert "the scan of instance 'u17'" in str(err.value)
    assert "in cycle 3 (t = 30 ms)" in str(err.value)
    assert not sim.plant.instances["u17"].m.slow.cell_contents  # it was a fast scan
    assert err.value.loc.line == 21


def self_plant(write: Callable[[str, str], str]) -> Plant:
    """An open virtual plant of one instance A of SELF: go on sim.I0, run on sim.Q0."""
    write("c.yaml", SELF)
    plant = Plant(load_plant(write(
        "p.yaml", "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\ninstances:\n"
        "  A: {grafcet: c.yaml, inputs: {go: sim.I0, stop: sim.I1}, outputs: {run: sim.Q0}}\n")),
        sim=True, virtual=True)
    plant.open()
    return plant


def test_the_inlined_scans_work_on_the_instances_own_state(
        write: Callable[[str, str], str]) -> None:
    """What the inlined scans write is what the instance's state view reads, and a write
    through the view is what the next scan sees (it takes the instance's whole scan)."""
    plant = self_plant(write)
    sim, a = plant.drivers["sim"], plant.instances["A"]
    for k in range(3):
        sim.inputs["I0"] = int(k >= 1)
        assert plant.cycle(k * 10_000_000) is None
        assert a.m.slow.cell_contents is False
    assert a.active_steps() == ["s1"] and a.get("run") is True and sim.outputs["Q0"]
    assert a.step_time("s1") == 10_000_000
    a.set("go", False)  # written between cycles: the next scan is the whole one
    assert a.m.slow.cell_contents is True
    sim.inputs["I0"] = 0
    plant.cycle(30_000_000)
    assert a.active_steps() == ["s0"] and sim.outputs["Q0"] == 0
    assert a.m.slow.cell_contents is False  # and back to the fast path


def test_the_one_test_of_the_usual_cycle_follows_every_change_of_what_it_sums_up(
        write: Callable[[str, str], str]) -> None:
    """``cycle`` tests one flag (``_usual``) where it tested seven attributes: after every
    console operation, force, pulse, online take-over and cycle, the flag is what the
    seven say, and an unusual cycle does what it must (a held plant does not scan)."""
    plant = self_plant(write)
    sim, a = plant.drivers["sim"], plant.instances["A"]

    def consistent() -> None:
        assert plant._usual == plant._is_usual()

    t = iter(range(0, 10**12, 10_000_000))
    consistent()
    plant.cycle(next(t))
    consistent()
    assert plant._usual
    ops: list[Callable[[], object]] = [
        plant.pause, lambda: plant.step(1), plant.resume, lambda: plant.set_iocheck(True),
        lambda: plant.set_iocheck(False), lambda: plant.force("A.go", True),
        lambda: plant.unforce("A.go"), lambda: plant.force("sim.I1", 1),
        lambda: plant.unforce(None), lambda: plant.pulse("A", "SFCInit"),
        lambda: setattr(plant, "hold", True), lambda: setattr(plant, "hold", False),
        lambda: setattr(plant, "iocheck", True), lambda: setattr(plant, "iocheck", False)]
    for op in ops:
        op()
        consistent()
        for _ in range(2):
            plant.cycle(next(t))
            consistent()
    plant.pause()
    sim.inputs["I0"] = 1
    before = plant.scans
    plant.cycle(next(t))
    assert plant.scans == before and a.active_steps() == ["s0"]  # held: not scanned
    plant.force("A.stop", False)
    other = self_plant(write)
    other.take_over(plant, lambda name: name)
    assert other._usual == other._is_usual() and not other._usual  # held, forced
    other.resume()
    other.unforce(None)
    assert other._usual == other._is_usual()


def test_the_chart_clock_goes_on_when_the_plant_start_moves(
        write: Callable[[str, str], str]) -> None:
    """The inlined scans share the plant's ``up`` as the chart clock of the instances that
    started with the plant (their base is its start): a start moved on a running plant
    (a review found it) starts the groups again, and the clock still goes on by ``now``."""
    plant = self_plant(write)
    a = plant.instances["A"]
    ct = a.program._by_key["#ct"]
    for k in range(5):
        plant.cycle(1_000_000_000 + k * 10_000_000)
    assert a.m[ct] == 40_000_000
    assert plant.start is not None
    plant.start = plant.start + 200_000_000
    plant.cycle(1_050_000_000)
    assert a.m[ct] == 50_000_000
    assert a.program.scan_time(a.m) == 1_050_000_000
    plant.cycle(1_060_000_000)
    assert a.m[ct] == 60_000_000


def test_scans_counts_every_cycle_that_scanned(
        write: Callable[[str, str], str]) -> None:
    """``scans`` counts the usual cycles and the forced ones, not the held ones."""
    plant = self_plant(write)
    t = iter(range(0, 10**12, 10_000_000))
    for _ in range(255):
        plant.cycle(next(t))
    assert plant.scans == 255
    plant.force("A.go", True)
    plant.cycle(next(t))  # a forced cycle: 256
    plant.unforce(None)
    plant.pause()
    plant.cycle(next(t))  # held: not counted
    plant.resume()
    for _ in range(300):
        plant.cycle(next(t))
    assert plant.scans == 556
    plant.scans = 1000  # as take_over sets it
    plant.cycle(next(t))
    assert plant.scans == 1001


def test_renaming_leaves_attributes_keywords_strings_and_comments() -> None:
    lines = ["x = b_t.q + f(IN=x, PT='x')  # x", "if x: y = {'x': x}[\"x\"]"]
    assert renamed(lines, lambda n: "i0_" + n if n in ("x", "y") else None) == [
        "i0_x = b_t.q + f(IN=i0_x, PT='x')  # x", "if i0_x: i0_y = {'x': i0_x}[\"x\"]"]


def test_links_across_groups_read_the_same_as_within_one(
        write: Callable[[str, str], str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Each group of inlined scans has its own copy of the cells it names: a link to an
    instance of another group, earlier or later in the plant, reads the same values as
    one inside a group (every slot of every instance compared, cycle by cycle)."""
    write("c.yaml", SELF)
    path = write("p.yaml", "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\ninstances:\n"
                 "  A: {grafcet: c.yaml, inputs: {go: sim.I0, stop: B.run}, "
                 "outputs: {run: sim.Q0}}\n"
                 "  B: {grafcet: c.yaml, inputs: {go: A.run, stop: sim.I1, SFCPause: C.run},"
                 " outputs: {run: sim.Q1}}\n"
                 "  C: {grafcet: c.yaml, inputs: {go: {from: B.run, invert: true}, "
                 "stop: sim.I2}, outputs: {run: sim.Q2}}\n")

    def run(group: int) -> list[list[object]]:
        monkeypatch.setattr(inline, "GROUP", group)
        pl = Plant(load_plant(path), sim=True, virtual=True)
        assert len(pl._inliner.sends) == 3 // group
        pl.open()
        sim, out = pl.drivers["sim"], []
        for k in range(40):
            sim.inputs["I0"] = int(k % 7 < 4)
            sim.inputs["I1"] = int(k % 11 == 3)
            pl.cycle(k * 10_000_000)
            out.append([v for i in pl.instances.values() for v in i.m[:]]
                       + [sim.outputs[q] for q in ("Q0", "Q1", "Q2")])
        return out
    assert run(1) == run(3)


COPY = """\
grafcet: Copy
inputs: [i, j]
outputs: [x, y]
pre: ["x := i", "y := i AND NOT j"]
steps:
  s0: {initial: true}
"""

#: per instance: (i's driver.point, j's, j inverted, y's driver.point, x's, x inverted);
#: bound out of order (outputs before inputs of lower numbers, y before x), across two
#: drivers and more instances than a group holds, so that positions differ from numbers
WIRING = [(f"{'ab'[k % 2]}.I{(7 * k) % 23}", f"{'ba'[k % 3 == 0]}.I{(5 * k + 11) % 23}",
           k % 4 == 1, f"{'ab'[k % 3 == 1]}.Q{(11 * k + 3) % 20}",
           f"{'ba'[k % 3 == 1]}.Q{(11 * k + 3) % 20}", k % 2 == 1) for k in range(20)]


def _binding(src: str, invert: bool) -> str:
    return f"{{from: {src}, invert: true}}" if invert else src


def test_the_cycle_reads_and_writes_the_bound_points_by_position(
        write: Callable[[str, str], str]) -> None:
    """The cycles read ``IL_d[k]`` and write ``OL_d[k] = ...`` on the images' lists, with
    positions resolved when the cycle is generated: every instance reads its own points and
    writes its own, whatever the binding order, inversions and drivers, in the fast cycle
    and in the slow one (checked by name against a model of the wiring, cycle by cycle)."""
    write("c.yaml", COPY)
    lines = ["plc: {cycle: 10ms}", "drivers: {a: {type: sim}, b: {type: sim}}",
             "instances:"]
    for k, (i, j, jinv, y, x, xinv) in enumerate(WIRING):
        lines.append(f"  k{k}: {{grafcet: c.yaml, inputs: {{j: {_binding(j, jinv)}, i: {i}}}, "
                     f"outputs: {{y: {y}, x: {_binding(x, xinv)}}}}}")
    path = write("p.yaml", "\n".join(lines) + "\n")
    ins = sorted({p for w in WIRING for p in w[:2]})
    for fast in (True, False):
        plant = Plant(load_plant(path), sim=True, virtual=True)
        plant.open()
        drv = plant.drivers
        # positions are in declaration order, not the points' numbers
        assert list(drv["a"].inputs.index.values()) == list(range(len(drv["a"].inputs)))
        assert list(drv["a"].inputs) != sorted(drv["a"].inputs, key=lambda p: int(p[1:]))
        assert "IL_a[" in plant.source and "OL_b[" in plant.source
        for c in range(12):
            # a fixed pseudo-random pattern of the inputs, another every cycle
            phys = {p: ((n * 2654435761 + c * 40503) >> 7) & 1 for n, p in enumerate(ins)}
            for p, v in phys.items():
                d, point = p.split(".")
                drv[d].inputs[point] = v
            if fast:
                assert plant.cycle(c * 10_000_000) is None
            else:
                plant._cycle(c * 10_000_000, c * 10_000_000)
            for k, (i, j, jinv, y, x, xinv) in enumerate(WIRING):
                vi, vj = bool(phys[i]), bool(phys[j]) != jinv
                d, q = y.split(".")
                assert bool(drv[d].outputs[q]) == (vi and not vj), (k, c, y)
                d, q = x.split(".")
                assert bool(drv[d].outputs[q]) == (vi != xinv), (k, c, x)


def test_a_handed_driver_keeps_its_points_positions_when_a_point_is_added(
        write: Callable[[str, str], str]) -> None:
    """An online change hands the open drivers to the new plant
    (``Plant(..., drivers=...)``). A point the new plant binds is appended to the handed
    driver's images: the old points keep their positions, so the old plant's captures
    and the new plant's cycle both read and write the right points."""
    write("c.yaml", COPY)
    head = "plc: {cycle: 10ms}\ndrivers: {sim: {type: sim}}\ninstances:\n"
    old = Plant(load_plant(write("p1.yaml", head +
                                 "  A: {grafcet: c.yaml, inputs: {i: sim.I4, j: sim.I2}, "
                                 "outputs: {x: sim.Q3, y: sim.Q1}}\n")), sim=True)
    old.open()
    sim = old.drivers["sim"]
    assert isinstance(sim, SimDriver)
    vals_in, vals_out = sim.inputs.vals, sim.outputs.vals
    sim.inputs.update({"I4": 1, "I2": 0})
    assert old.cycle(0) is None and sim.outputs.copy() == {"Q3": True, "Q1": True}
    # the new plant: a new instance B on new points I0 and Q0, declared before A's
    new = Plant(load_plant(write("p2.yaml", head +
                                 "  B: {grafcet: c.yaml, inputs: {i: sim.I0, j: sim.I4}, "
                                 "outputs: {x: sim.Q0, y: sim.Q3}}\n"
                                 "  A: {grafcet: c.yaml, inputs: {i: sim.I4, j: sim.I2}, "
                                 "outputs: {x: sim.Q2, y: sim.Q1}}\n")),
                sim=True, drivers={"sim": sim})
    assert new.drivers["sim"] is sim
    assert sim.inputs.vals is vals_in and sim.outputs.vals is vals_out
    assert sim.inputs.index == {"I4": 0, "I2": 1, "I0": 2}
    assert sim.outputs.index == {"Q3": 0, "Q1": 1, "Q0": 2, "Q2": 3}
    old.dispose()
    sim.inputs.update({"I0": 1, "I4": 0, "I2": 0})
    for k in (1, 2):
        assert new.cycle(k * 10_000_000) is None
        # B: x = I0, y = I0 and not I4; A: x = I4 (Q2), y = I4 and not I2 (Q1)
        assert sim.outputs.copy() == {"Q3": True, "Q1": False, "Q2": False, "Q0": True}
        assert sim.written == sim.outputs.copy()


def test_a_group_that_ended_is_started_again_with_the_state_kept(
        write: Callable[[str, str], str], caplog: pytest.LogCaptureFixture) -> None:
    """A group of inlined scans is a generator: an exception raised where no scan catches
    it (at its resume, e.g. from a signal handler in the main thread) ends it. Before, every
    later cycle raised StopIteration for good (a review found it); now that cycle fails, the
    group is started again, and the next cycle goes on from the instances' state."""
    plant = self_plant(write)
    sim, a = plant.drivers["sim"], plant.instances["A"]
    sim.inputs["I0"] = 1
    for k in range(3):
        plant.cycle(k * 10_000_000)
    assert a.active_steps() == ["s1"] and a.step_time("s1") == 10_000_000
    plant._inliner._gens[0].close()  # as an exception at its resume would end it
    with pytest.raises(StopIteration):
        plant.cycle(30_000_000)
    assert "inlined scans of group 0 started again" in caplog.text
    plant.cycle(40_000_000)
    assert a.active_steps() == ["s1"] and sim.outputs["Q0"]
    assert a.step_time("s1") == 30_000_000  # the failed cycle did not scan
