"""``softplc draw`` and ``softplc chronogram``: the SVG parses and names what it shows."""

from __future__ import annotations

import argparse
import json
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.drawing import chart as draw
from runtime.drawing import chronogram as chrono
from runtime.drawing import text as draw_text
from runtime.errors import SourceError
from runtime.language.grafcetfile import load_grafcet
from runtime.language.plantfile import load_plant

ROOT = Path(__file__).resolve().parents[2]

SVG = "{http://www.w3.org/2000/svg}"
LAYOUTS = ["python"] + (["dot"] if shutil.which("dot") else [])

MACRO = """\
grafcet: Reactor
inputs: [iMarcha, iNivelA, iNivelB, iEmergencia, iAck, iFin, iPieza]
outputs: [oValvA, oValvB, oMotor, oAlarma, oVaciar]
memory: {sPiezas: 0}
steps:
  gsParado: {initial: true, actions: ["P1 sPiezas := 0"]}
  gsLlenado:
    macro:
      steps:
        eLlenarA: {entry: true, actions: [oValvA, "D 2s oMotor"]}
        eLlenarB: {actions: ["N oValvB if iNivelA"]}
        sLleno: {exit: true}
      transitions:
        - {from: eLlenarA, to: eLlenarB, when: iNivelA}
        - {from: eLlenarB, to: sLleno, when: iNivelB}
  gsAgitar: {actions: [oMotor, "on ↑iPieza do sPiezas := sPiezas + 1"]}
  gsVaciar: {actions: [oVaciar]}
  gsEsperaA: {}
  gsEsperaB: {}
  gsAlarma: {actions: [oAlarma]}
transitions:
  - {from: gsParado, to: gsLlenado, when: "↑iMarcha"}
  - {from: gsLlenado, to: [gsAgitar, gsVaciar], when: "1"}
  - {from: gsAgitar, to: gsEsperaA, when: iFin}
  - {from: gsVaciar, to: gsEsperaB, when: "iFin'"}
  - {from: [gsEsperaA, gsEsperaB], to: gsParado, when: "1"}
  - {from: [], to: gsAlarma, when: ↑iEmergencia}
  - {from: gsAlarma, to: [], when: iAck}
"""

PLANT = """\
plc: {cycle: 10ms}
drivers:
  sim: {type: sim}
instances:
  t1:
    grafcet: drawer.yaml
    inputs:
      iParo: {from: sim.I0, invert: true}
      iMarcha: sim.I1
      iAbierto: sim.I2
      iCerrado: sim.I3
    outputs: {oAbrir: sim.Q0, oCerrar: sim.Q1, oParado: sim.Q2, oTest: sim.Q3}
  t2:
    grafcet: drawer.yaml
    inputs:
      iParo: {from: sim.I10, invert: true}
      iMarcha: sim.I11
      iAbierto: sim.I12
      iCerrado: sim.I13
    outputs: {oAbrir: sim.Q10, oCerrar: sim.Q11, oParado: sim.Q12, oTest: sim.Q13}
"""

SCRIPT = """\
duration: 300ms
set:
  - {at: 0ms, sim.I0: 1, sim.I10: 1}
  - {at: 25ms, t1.iMarcha: 1}
  - {at: 60ms, t1.iMarcha: 0, t1.iAbierto: 1}
"""


def texts(svg_path: str) -> list[str]:
    root = ET.parse(svg_path).getroot()
    assert root.tag == f"{SVG}svg"
    return ["".join(t.itertext()) for t in root.iter(f"{SVG}text")]


@pytest.fixture
def trace(write: Callable[[str, str], str], drawer: str, tmp_path: Path) -> str:
    from runtime.engine.simulate import Simulation, write_trace

    sim = Simulation(write("plant.yaml", PLANT), write("script.yaml", SCRIPT))
    out = tmp_path / "trace.jsonl"
    with open(out, "w", encoding="utf-8") as f:
        write_trace(iter(list(sim.run(trace=True))), f)
    return str(out)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_draw_names_every_step_and_condition(drawer: str, tmp_path: Path, layout: str) -> None:
    out = str(tmp_path / "d.svg")
    assert draw.draw(drawer, out, layout=layout) == layout
    found = texts(out)
    g = load_grafcet(drawer)
    for s in g.steps:
        assert s in found, s
    for t in g.transitions:  # the drawer tester is written in the seed notation already
        assert t.text in found, t.text
        assert draw_text.seed_text(t.cond) == t.text
    assert "oAbrir" in found and "P1" in found


@pytest.mark.parametrize("layout", LAYOUTS)
def test_draw_macro_and_parallel(write: Callable[[str, str], str], tmp_path: Path,
                                 layout: str) -> None:
    path = write("macro.yaml", MACRO)
    out = str(tmp_path / "m.svg")
    draw.draw(path, out, layout=layout)
    found = texts(out)
    for s in load_grafcet(path).leaf_steps():
        assert s.name in found
    assert "D 2s" in found and "↑iPieza" in found and "oValvB if iNivelA" in found
    root = ET.parse(out).getroot()
    initial = [r for r in root.iter(f"{SVG}rect") if r.get("class") == "initial"]
    assert len(initial) == 1  # gsParado's inner box
    and_lines = [p for p in root.iter(f"{SVG}polyline") if "and" in (p.get("class") or "").split()]
    assert len(and_lines) == 4  # one divergence and one convergence, two lines each
    assert "gsLlenado (macro-step)" in found
    assert len([r for r in root.iter(f"{SVG}rect") if r.get("class") == "macro"]) == 1


@pytest.mark.parametrize("layout", LAYOUTS)
def test_draw_marks_active_steps_of_a_scan(drawer: str, trace: str, tmp_path: Path,
                                           layout: str) -> None:
    rows = [json.loads(x) for x in Path(trace).read_text().splitlines()]
    k = next(r["cycle"] for r in rows if r["t1.gsAbrir.X"] == 1)
    out = str(tmp_path / "a.svg")
    draw.draw(drawer, out, trace=trace, cycle=k, instance="t1", layout=layout)
    root = ET.parse(out).getroot()
    filled = [r for r in root.iter(f"{SVG}rect")
              if r.get("class") == "step" and r.get("fill") == draw.ACTIVE_FILL]
    assert len(filled) == 1
    assert len([c for c in root.iter(f"{SVG}circle") if c.get("class") == "token"]) == 1
    assert any(f"cycle {k}" in t for t in texts(out))


def test_draw_needs_instance_when_ambiguous(drawer: str, trace: str, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    draw.register(sub)
    args = p.parse_args(["draw", drawer, "-o", str(tmp_path / "x.svg"), "--trace", trace,
                         "--cycle", "3"])
    assert args.func(args) == 2
    assert "pick one with --instance" in capsys.readouterr().err
    args = p.parse_args(["draw", drawer, "-o", str(tmp_path / "x.svg"), "--trace", trace,
                         "--cycle", "3", "--instance", "t2", "--layout", "python"])
    assert args.func(args) == 0
    assert ET.parse(tmp_path / "x.svg").getroot().tag == f"{SVG}svg"


def test_draw_a_plant_instance(write: Callable[[str, str], str], drawer: str,
                               tmp_path: Path) -> None:
    plant = write("plant.yaml", PLANT)
    out = str(tmp_path / "p.svg")
    draw.draw(plant, out, instance="t2", layout="python")
    assert "gsCerrar" in texts(out)


def signal_rows(svg_path: str) -> list[tuple[str, str]]:
    """(key, label) of every row of a chronogram, top to bottom."""
    root = ET.parse(svg_path).getroot()
    return [(t.get("data-key", ""), "".join(t.itertext())) for t in root.iter(f"{SVG}text")
            if t.get("class") == "signal"]


def test_chronogram_default_groups(trace: str, tmp_path: Path) -> None:
    out = str(tmp_path / "c.svg")
    n = chrono.chronogram(trace, out, cycle=5)
    found = texts(out)
    keys = dict(signal_rows(out))
    for key in ("t1.iMarcha", "t1.gsAbrir.X", "t1.oAbrir", "t1.sCierres", "t2.gsParado.X"):
        assert key in keys
        assert keys[key] == key.split(".", 1)[1]  # the heading names the instance
    assert "t1: inputs" in found and "t1: steps" in found and "t1: outputs" in found
    assert "cycle 5" in found
    assert n == 2 * (4 + 4 + 4 + 2)
    assert not any(k.endswith(".T_ms") or k.startswith("sim.") for k in keys)


def test_chronogram_window_title_and_order(trace: str, tmp_path: Path) -> None:
    out = str(tmp_path / "w.svg")
    n = chrono.chronogram(trace, out, ["t1.oAbrir", "t1.iMarcha", "t1.gsAbrir.X"],
                          start=20.0, end=100.0, title="Story of t1")
    assert n == 3
    assert [k for k, _ in signal_rows(out)] == ["t1.oAbrir", "t1.iMarcha", "t1.gsAbrir.X"]
    found = texts(out)
    assert "Story of t1" in found
    # headings follow the selection: outputs, inputs, steps
    assert [t for t in found if t.startswith("t1: ")] == ["t1: outputs", "t1: inputs",
                                                            "t1: steps"]
    ticks = [t for t in found if t.endswith(" ms") or t == "0"]
    assert ticks and ticks[0] == "20 ms" and ticks[-1] in ("100 ms", "110 ms")
    with pytest.raises(SourceError, match="no scan between 500 and 600 ms"):
        chrono.chronogram(trace, out, start=500.0, end=600.0)
    assert chrono.parse_ms("2s", "--to") == 2000.0
    assert chrono.parse_ms("1500ms", "--to") == 1500.0
    assert chrono.parse_ms("250", "--to") == 250.0
    assert chrono.parse_ms("T#1m", "--to") == 60000.0
    with pytest.raises(SourceError, match="expected a time"):
        chrono.parse_ms("soon", "--to")


def test_chronogram_selected_signals_and_bands(trace: str, tmp_path: Path,
                                              write: Callable[[str, str], str]) -> None:
    out = str(tmp_path / "c.svg")
    n = chrono.chronogram(trace, out, ["iMarcha", "t1.gs*.X", "t1.SFCCurrentStep"])
    assert n == 2 + 4 + 1
    found = texts(out)
    assert "gsAbrir" in found  # a text band shows its value
    with pytest.raises(Exception, match="no signal 'iNada'"):
        chrono.chronogram(trace, out, ["iNada"])


def test_chronogram_numbers_as_bands(tmp_path: Path) -> None:
    rows = [{"cycle": k, "t_ms": 10 * k, "a.iX": k % 2, "a.sN": k // 3, "a.SFCInit": 0}
            for k in range(12)]
    trace = tmp_path / "t.jsonl"
    trace.write_text("".join(json.dumps(r) + "\n" for r in rows))
    out = str(tmp_path / "n.svg")
    chrono.chronogram(str(trace), out)
    root = ET.parse(out).getroot()
    assert len(list(root.iter(f"{SVG}polygon"))) == 4  # sN: 0, 1, 2, 3
    assert {"0", "1", "2", "3"} <= set(texts(out))


def test_chronogram_cli(trace: str, tmp_path: Path,
                        capsys: pytest.CaptureFixture[str]) -> None:
    p = argparse.ArgumentParser()
    sub = p.add_subparsers()
    chrono.register(sub)
    args = p.parse_args(["chronogram", trace, "-o", str(tmp_path / "c.svg"), "--signals",
                         "t1.oAbrir"])
    assert args.func(args) == 0
    args = p.parse_args(["chronogram", trace, "-o", str(tmp_path / "c.svg"), "--from", "50ms",
                         "--to", "0.2s", "--title", "T"])
    assert args.func(args) == 0
    assert "T" in texts(str(tmp_path / "c.svg"))
    args = p.parse_args(["chronogram", trace, "-o", str(tmp_path / "c.svg"), "--from", "1s",
                         "--to", "2s"])
    assert args.func(args) == 2
    assert "error: no scan between 1000 and 2000 ms" in capsys.readouterr().err
    args = p.parse_args(["chronogram", str(tmp_path / "none.jsonl"), "-o",
                         str(tmp_path / "c.svg")])
    assert args.func(args) == 2


def test_chronogram_plant_keeps_the_macro_step_row(tmp_path: Path) -> None:
    """With --plant, a macro-step's .X (true while its expansion runs) has its row among
    the steps, in file order, as without --plant."""
    from runtime.engine.simulate import Simulation, write_trace

    plant = ROOT / "configs/reactor/plant_sim.yaml"
    sim = Simulation(str(plant), str(ROOT / "configs/reactor/story.yaml"))
    trace = tmp_path / "trace.jsonl"
    with open(trace, "w", encoding="utf-8") as f:
        write_trace(iter(list(sim.run(trace=True))), f)
    inst = next(iter(load_plant(str(plant)).instances))
    plain, exact = str(tmp_path / "plain.svg"), str(tmp_path / "plant.svg")
    chrono.chronogram(str(trace), plain)
    chrono.chronogram(str(trace), exact, plant=str(plant))
    rows = [k for k, _ in signal_rows(exact)]
    assert f"{inst}.gsAgitacion.X" in rows
    steps = [k for k in rows if k.startswith(inst + ".") and k.endswith(".X")]
    assert steps == [k for k, _ in signal_rows(plain) if k in steps]
    assert steps.index(f"{inst}.gsAgitacion.X") < steps.index(f"{inst}.eDerecha.X")
