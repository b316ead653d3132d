"""What Beremiz's own projects hold, in test files written here in its style: each imports
as the chart written by hand below, runs on the plant skeleton scan by scan against
expectations worked out by hand, and round-trips (export then import: the same chart, and
``softplc diff`` says "no change").

- beremiz_cell.xml: function blocks in the SFC body's network (R_TRIG, TON), in a POU
  transition's FBD body (SR) and in a POU action's LD body (CTU); LD contacts, coils, set and
  reset coils; action blocks with S, R, D (duration), P and no qualifier; a jump step; a
  comment in the SFC body; located variables and documentation.
- beremiz_globals.xml: configuration and resource globals, constant and not, reached by
  VAR_EXTERNAL (a resource's global hides its configuration's of the same name).
- beremiz_line.xml: a program in FBD instantiating an SFC function block twice, wired to its
  variables and to each other: a plant of two instances.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from runtime.cli import main
from runtime.engine.simulate import Simulation
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import load_plant
from tests.plcopen.plcopenkit import DATA, export_file, shape

CELL = DATA / "beremiz_cell.xml"
GLOBALS = DATA / "beremiz_globals.xml"
LINE = DATA / "beremiz_line.xml"

#: what beremiz_cell.xml means: the blocks of the conditions' networks called in post
#: (every scan, after the actions: Beremiz makes them an S action of the initial step), the
#: LD action as statements in Beremiz's order (outputs top to bottom, each after the calls
#: it reads), the comments as the description and as // lines
CELL_CHART = """\
grafcet: Cell
description: |
  Press cell: a start edge readies the press,
  the heater's timer lets it run, three parts finish a batch.
inputs:
  - Start: {type: bool, description: Start button (NO)}
  - Stop
  - Heat: {type: bool, description: Heater at temperature}
  - Part
  - Estop: {type: bool, description: "Emergency stop, NC contact"}
outputs:
  - Motor: {type: bool, description: Conveyor motor}
  - Lamp
  - Horn
  - Full
  - Parts: {type: int, description: Parts pressed in this batch, iec_type: INT}
  - Beacon: {type: bool, description: Beacon on the frame}
memory:
  Seen: false
blocks: {StartEdge: R_TRIG, Warm: TON, Cnt: CTU, Hold: SR}
steps:
  Idle:
    initial: true
    actions: [N Lamp, R Motor]
  Ready:
    actions: [S Motor, P Horn]
  Run:
    actions:
      - |
        N (* action Counting *) // Counts the parts while the press runs
        Cnt(CU := Part, PV := 3)
        Full := Cnt.Q
        Parts := Cnt.CV
        IF Full THEN Seen := TRUE; END_IF
        IF Stop THEN Seen := FALSE; END_IF
        Beacon := NOT Part
      - D T#300ms Horn
transitions:
  - {from: Idle, to: Ready, when: StartEdge.Q AND NOT Stop}
  - {from: Ready, to: Run, when: Warm.Q}
  - {from: Run, to: Idle, when: Hold.Q1 OR NOT Estop, name: Finished}
post:
  - StartEdge(CLK := Start)
  - Warm(IN := Heat, PT := T#500ms)
  - Hold(S1 := Seen, R := Stop)
"""

#: the resource's Increment (2) hides the configuration's (100); names written in another
#: case are spelled as declared; the located global is an output
GLOBALS_CHART = """\
grafcet: Batcher
inputs: [Go]
outputs:
  - Alarm: {type: bool, description: Batch full horn}
memory:
  Limit: {init: 3, iec_type: INT}
  Increment: {init: 2, iec_type: INT}
  Enable: true
  Total: {init: 0, description: Parts counted since power-up, iec_type: INT}
steps:
  Idle: {initial: true}
  Add:
    actions: ["P Total := Total + Increment;"]
  Full:
    actions: [N Alarm, "P Enable := FALSE;"]
transitions:
  - {from: Idle, to: Add, when: Go AND Enable}
  - {from: Add, to: Full, when: Total >= Limit}
  - {from: Add, to: Idle, when: NOT Go}
  - {from: Full, to: Idle, when: NOT Go}
"""

STAGE_CHART = """\
grafcet: Stage
inputs:
  - Arrive: {type: bool, description: A part is at the stage}
  - Enable
outputs: [Busy, {Passed: {type: int, iec_type: INT}}]
steps:
  Wait: {initial: true}
  Work:
    actions: [N Busy, "P Passed := Passed + 1;"]
transitions:
  - {from: Wait, to: Work, when: Arrive AND Enable}
  - {from: Work, to: Wait, when: NOT Arrive}
"""

#: the plant beremiz_line.xml's program Line is: one instance per function block instance,
#: in the order its body calls them; the program's variables as points (their addresses and
#: documentation kept), stage 2's Enable the negated Busy of stage 1
LINE_PLANT = """\
  Stage1:
    grafcet: Stage.yaml
    inputs:
      Arrive: {from: sim.I0, at: "%IX0.0", description: "Sensor at stage 1"}  # Sensor1 of Line
      Enable: {from: sim.I1, description: "Line running"}  # Run of Line
    outputs:
      Busy: {from: sim.Q0, at: "%QX0.0", description: "Stage 1 lamp"}  # Busy1 of Line
      Passed: sim.HR0
  Stage2:
    grafcet: Stage.yaml
    inputs:
      Arrive: {from: sim.I2, at: "%IX0.1"}  # Sensor2 of Line
      Enable: {from: Stage1.Busy, invert: true}
    outputs:
      Busy: sim.Q1
      Passed: sim.HR1  # Count2 of Line
"""

Spans = list[tuple[int, int]]  # [from, to) in ms


def within(t: int, spans: Spans) -> int:
    return int(any(a <= t < b for a, b in spans))


def imported(tmp_path: Path, xml: Path, capsys: pytest.CaptureFixture[str]) -> Path:
    out = tmp_path / "out"
    assert main(["import", str(xml), "-o", str(out), "--strict"]) == 0, (
        capsys.readouterr().err)
    capsys.readouterr()
    return out


def run(plant: Path, script: str, tmp_path: Path) -> list[dict[str, Any]]:
    s = tmp_path / "script.yaml"
    s.write_text(script, encoding="utf-8")
    return list(Simulation(str(plant), str(s)).run(trace=True))


def expected(tmp_path: Path, text: str) -> dict[str, object]:
    p = tmp_path / "expected.yaml"
    p.write_text(text, encoding="utf-8")
    return shape(load_grafcet(str(p)))


@pytest.mark.parametrize(("xml", "pou", "chart"), [
    (CELL, "Cell", CELL_CHART), (GLOBALS, "Batcher", GLOBALS_CHART),
    (LINE, "Stage", STAGE_CHART)])
def test_imports_as_the_chart_it_means_and_round_trips(
        xml: Path, pou: str, chart: str, tmp_path: Path,
        capsys: pytest.CaptureFixture[str], tc6: Any) -> None:
    out = imported(tmp_path, xml, capsys)
    g = load_grafcet(str(out / f"{pou}.yaml"))
    assert shape(g) == expected(tmp_path, chart)
    assert [v.description for v in g.variables.values()] == [
        v.description for v in load_grafcet(str(tmp_path / "expected.yaml")).variables.values()]
    # export then import: the same chart, and softplc diff says so
    back_xml = export_file(g, tmp_path / "back.xml")
    tc6.validate(str(back_xml))
    assert main(["import", str(back_xml), "-o", str(tmp_path / "back"), "--strict"]) == 0
    back = tmp_path / "back" / f"{pou}.yaml"
    assert shape(load_grafcet(str(back))) == shape(g)
    capsys.readouterr()
    assert main(["diff", str(out / f"{pou}.yaml"), str(back)]) == 0
    assert capsys.readouterr().out == "no change\ncan be applied online\n"


CELL_STORY = """\
duration: 1500ms
set:
  - {at: 0ms, cell.Estop: 1, cell.Heat: 1}
  - {at: 100ms, cell.Part: 1}
  - {at: 200ms, cell.Part: 0, cell.Start: 1}
  - {at: 300ms, cell.Start: 0}
  - {at: 700ms, cell.Part: 1}
  - {at: 800ms, cell.Part: 0}
  - {at: 900ms, cell.Part: 1}
  - {at: 1000ms, cell.Part: 0}
  - {at: 1100ms, cell.Part: 1}
  - {at: 1200ms, cell.Part: 0}
"""

#: worked out by hand (cycle 100 ms, the task's): Start rises at 200, StartEdge (called in
#: post) sees it at the end of that scan, so Idle -> Ready fires at 300, one scan later
#: than an ST 'RE Start' would; Warm times Heat from scan 0 though Ready is active only
#: from 300 (a block of a condition runs every scan), its Q is set by the call at 500 and
#: read at 600; the CTU runs only while Run's action does, so the part at 100 is not
#: counted, those at 700, 900, 1100 are; Full at 1100 sets Seen, Hold (post) sets Q1 at the
#: end of that scan, and Finished leaves Run at 1200
CELL_STEPS: dict[str, Spans] = {
    "Idle": [(0, 300), (1200, 9999)], "Ready": [(300, 600)], "Run": [(600, 1200)]}


def test_cell_scan_by_scan(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rows = run(imported(tmp_path, CELL, capsys) / "plant.yaml", CELL_STORY, tmp_path)
    assert len(rows) == 15
    for r in rows:
        t = r["t_ms"]
        want = {f"cell.{s}.X": within(t, spans) for s, spans in CELL_STEPS.items()}
        want["cell.Lamp"] = want["cell.Idle.X"]  # N (no qualifier) in Idle
        want["cell.Motor"] = within(t, [(300, 1200)])  # S in Ready, R in Idle
        want["cell.Horn"] = within(t, [(300, 400), (900, 1200)])  # P in Ready, D 300ms in Run
        want["cell.Parts"] = (t >= 700) + (t >= 900) + (t >= 1100)
        want["cell.Full"] = want["cell.Seen"] = int(t >= 1100)
        # NOT Part while Counting runs (600..1100), then as the last run left it
        want["cell.Beacon"] = (0 if t < 600 else 1 - (t // 100) % 2 if t <= 1100 else 0)
        want["cell.StartEdge.Q"] = int(t == 200)
        want["cell.Warm.Q"] = int(t >= 500)
        want["cell.Hold.Q1"] = int(t >= 1100)
        got = {k: r[k] for k in want}
        assert got == want, f"t = {t} ms"


GLOBALS_STORY = """\
duration: 1100ms
set:
  - {at: 100ms, batcher.Go: 1}
  - {at: 300ms, batcher.Go: 0}
  - {at: 500ms, batcher.Go: 1}
  - {at: 700ms, batcher.Go: 0}
  - {at: 900ms, batcher.Go: 1}
"""


def test_globals_scan_by_scan(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Total adds the resource's Increment (2) at each entry into Add; at 4 it reaches the
    configuration's Limit (3): Full sounds the located Alarm and clears Enable, so Go at
    900 starts nothing."""
    rows = run(imported(tmp_path, GLOBALS, capsys) / "plant.yaml", GLOBALS_STORY, tmp_path)
    assert len(rows) == 11
    for r in rows:
        t = r["t_ms"]
        want = {"batcher.Idle.X": within(t, [(0, 100), (300, 500), (700, 9999)]),
                "batcher.Add.X": within(t, [(100, 300), (500, 600)]),
                "batcher.Full.X": within(t, [(600, 700)]),
                "batcher.Alarm": within(t, [(600, 700)]), "sim.Q0": within(t, [(600, 700)]),
                "batcher.Total": 2 * ((t >= 100) + (t >= 500)),
                "batcher.Enable": int(t < 600), "batcher.Limit": 3, "batcher.Increment": 2}
        assert {k: r[k] for k in want} == want, f"t = {t} ms"


def test_globals_notes_say_where_each_external_comes_from(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["import", str(GLOBALS), "-o", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert (f"{GLOBALS}:35:13: note: VAR_EXTERNAL CONSTANT 'Increment': the global of "
            "resource 'resource1' (line 271) is memory of the chart with its initial value"
            ) in err
    assert (f"{GLOBALS}:52:13: note: VAR_EXTERNAL 'Alarm': the global of resource "
            "'resource1' (line 289) is an output of the chart") in err
    assert 'Alarm: {from: sim.Q0, at: "%QX0.1"}' in (
        tmp_path / "plant.yaml").read_text(encoding="utf-8")


def test_a_chart_that_writes_a_constant_is_refused(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    xml = tmp_path / "g.xml"
    xml.write_text(GLOBALS.read_text(encoding="utf-8").replace(
        "Enable := FALSE;", "Limit := 5;"), encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"{xml}:300:11: error: 'Limit' is CONSTANT in the file and the chart writes it (IEC "
        "61131-3 refuses that)")


def test_an_external_with_no_global_is_refused(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    xml = tmp_path / "g.xml"
    xml.write_text(GLOBALS.read_text(encoding="utf-8").replace(
        '<variable name="Enable">', '<variable name="Enabled">', 1), encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        f"{xml}:42:13: error: VAR_EXTERNAL 'Enabled': no global variable of that name in the "
        "configuration or resource that runs the POU")


LINE_STORY = """\
duration: 500ms
set:
  - {at: 0ms, Stage1.Enable: 1}
  - {at: 100ms, Stage1.Arrive: 1}
  - {at: 150ms, Stage2.Arrive: 1}
  - {at: 250ms, Stage1.Arrive: 0}
  - {at: 350ms, Stage2.Arrive: 0}
"""


def test_a_program_of_function_block_instances_is_a_plant(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = imported(tmp_path, LINE, capsys)
    text = (out / "plant.yaml").read_text(encoding="utf-8")
    assert "  cycle: 50ms\n" in text  # the task of the program
    assert "# Comment of program Line: Stage 2 takes a part only while stage 1 is idle\n" in text
    assert text.split("instances:\n", 1)[1].rsplit("# written by", 1)[0] == LINE_PLANT
    assert list(load_plant(str(out / "plant.yaml")).instances) == ["Stage1", "Stage2"]


def test_the_line_scan_by_scan(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Stage 2 takes its part only once stage 1 is idle again: at 250, in the scan stage 1
    leaves Work (stage 1 is scanned first, so stage 2 reads this cycle's Busy)."""
    rows = run(imported(tmp_path, LINE, capsys) / "plant.yaml", LINE_STORY, tmp_path)
    assert len(rows) == 10
    for r in rows:
        t = r["t_ms"]
        want = {"Stage1.Work.X": within(t, [(100, 250)]), "Stage1.Passed": int(t >= 100),
                "Stage2.Work.X": within(t, [(250, 350)]), "Stage2.Passed": int(t >= 250),
                "Stage2.Enable": 1 - within(t, [(100, 250)]),
                "sim.Q0": within(t, [(100, 250)]), "sim.HR1": int(t >= 250)}
        assert {k: r[k] for k in want} == want, f"t = {t} ms"


def test_what_a_program_cannot_carry_is_one_line_each(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A block of another POU type and an input wired to an expression: one warning each,
    the input bound to a point of its own."""
    text = LINE.read_text(encoding="utf-8")
    xml = tmp_path / "l.xml"
    xml.write_text(text.replace("<expression>Sensor2</expression>",
                                "<expression>Sensor2 AND Run</expression>"), encoding="utf-8")
    assert main(["import", str(xml), "-o", str(tmp_path / "o")]) == 0
    err = capsys.readouterr().err
    assert ("warning: input Arrive of instance 'Stage2' is wired to 'Sensor2 AND Run' in "
            "program 'Line': bound to a point of its own") in err
    plant = (tmp_path / "o" / "plant.yaml").read_text(encoding="utf-8")
    assert "      Arrive: sim.I2\n" in plant
