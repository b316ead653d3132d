"""The ``simulate`` contract of language.md: virtual clock, script timing, trace keys."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from runtime.engine.simulate import Simulation
from runtime.errors import SourceError

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
"""

SCRIPT = """\
duration: 200ms
set:
  - {at: 0ms, sim.I0: 1}
  - {at: 25ms, t1.iMarcha: 1}
  - {at: 60ms, t1.iMarcha: 0, t1.iAbierto: 1}
  - {at: 100ms, t1.iParo: 1}
  - {at: 150ms, t1.SFCPause: 1}
"""


@pytest.fixture
def sim(write, drawer):  # type: ignore[no-untyped-def]
    return Simulation(write("plant.yaml", PLANT), write("script.yaml", SCRIPT))


def test_scans_at_k_cycle_while_t_below_duration(sim):  # type: ignore[no-untyped-def]
    rows = list(sim.run())
    assert [r["t_ms"] for r in rows] == list(range(0, 200, 10))
    assert [r["cycle"] for r in rows] == list(range(20))


def test_a_change_is_seen_by_the_first_scan_at_or_after_its_time(sim):  # type: ignore
    rows = list(sim.run())
    marcha = [r["t1.iMarcha"] for r in rows]
    assert marcha[:3] == [0, 0, 0] and marcha[3] == 1  # set at 25 ms -> scan at 30 ms
    assert rows[3]["t1.gsAbrir.X"] == 1  # the edge fires in that very scan (immediate)
    assert rows[6]["t1.iAbierto"] == 1 and rows[5]["t1.iAbierto"] == 0


def test_logical_keys_write_the_physical_point_through_the_inversion(sim):  # type: ignore
    rows = list(sim.run())
    assert rows[9]["t1.iParo"] == 0 and rows[9]["sim.I0"] == 1
    assert rows[10]["t1.iParo"] == 1 and rows[10]["sim.I0"] == 0  # NC: stop = contact open


def test_cycle_zero_activates_initial_steps_and_fires_nothing(write, drawer):  # type: ignore
    script = write("s.yaml", "cycles: 2\nset:\n  - {at: 0ms, t1.iMarcha: 1, sim.I0: 1}\n")
    rows = list(Simulation(write("plant.yaml", PLANT), script).run())
    assert rows[0]["t1.gsParado.X"] == 1 and rows[0]["t1.gsAbrir.X"] == 0
    # start held at power-up: no edge on the first scan, and none later either
    assert rows[1]["t1.gsAbrir.X"] == 0


def test_trace_holds_every_kind_of_value(sim):  # type: ignore[no-untyped-def]
    row = list(sim.run())[12]
    for key in ("t1.iMarcha", "t1.oAbrir", "t1.gsAbrir.X", "t1.gsAbrir.T_ms", "t1.sCierres",
                "t1.SFCPause", "t1.SFCCurrentStep", "sim.I0", "sim.Q0", "sim.ok"):
        assert key in row, key
    assert row["t1.SFCCurrentStep"] == "gsCerrar"
    assert isinstance(row["t1.gsCerrar.T_ms"], int)
    assert all(v in (0, 1) for k, v in row.items() if k.endswith(".X"))


def test_chart_flags_can_be_driven(sim):  # type: ignore[no-untyped-def]
    rows = list(sim.run())
    assert rows[15]["t1.SFCPause"] == 1
    assert rows[14]["t1.SFCPause"] == 0


def test_cycles_override_and_determinism(write, drawer):  # type: ignore[no-untyped-def]
    p, s = write("plant.yaml", PLANT), write("script.yaml", SCRIPT)
    a = list(Simulation(p, s, cycles=7).run())
    b = list(Simulation(p, s, cycles=7).run())
    assert len(a) == 7 and a == b


def test_bad_script_key_names_the_place(write, drawer):  # type: ignore[no-untyped-def]
    s = write("bad.yaml", "cycles: 3\nset:\n  - {at: 0ms, t1.iMarch: 1}\n")
    with pytest.raises(SourceError) as e:
        Simulation(write("plant.yaml", PLANT), s)
    assert e.value.loc.line == 3 and "iMarcha" in e.value.message


def test_cli_writes_trace_and_vcd(write, drawer, tmp_path):  # type: ignore[no-untyped-def]
    p, s = write("plant.yaml", PLANT), write("script.yaml", SCRIPT)
    trace, vcd = tmp_path / "t.jsonl", tmp_path / "t.vcd"
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "simulate", p, "--script", s,
                        "--trace", str(trace), "--vcd", str(vcd)], capture_output=True,
                       text=True, check=False)
    assert r.returncode == 0, r.stderr
    lines = trace.read_text().splitlines()
    assert len(lines) == 20 and json.loads(lines[0])["cycle"] == 0
    text = vcd.read_text()
    assert "$enddefinitions" in text and "t1.gsAbrir.X" in text and "#30" in text


TYPED = """\
grafcet: Typed
inputs: [iGo, {iN: int}]
outputs: [oRun, {oN: int}]
memory: {sWait: 1500ms, sK: 0, sR: 0.5}
blocks: {ton: TON}
pre:
  - ton(IN := iGo, PT := 50ms)
steps:
  s0: {initial: true}
  s1: {actions: [oRun, "N oN := iN * 2", "P1 sK := sK + 1"]}
transitions:
  - {from: s0, to: s1, when: ton.Q}
"""

TYPED_PLANT = """\
plc: {cycle: 10ms}
drivers: {sim: {type: sim}, io: {type: sim}}
instances:
  a:
    grafcet: typed.yaml
    inputs: {iGo: sim.I0, iN: sim.IR0}
    outputs: {oRun: sim.Q0, oN: io.HR0}
  b:
    grafcet: typed.yaml
    inputs: {iGo: a.oRun, iN: a.oN}
    outputs: {oRun: io.Q0, oN: io.HR1}
"""


def test_trace_keys_are_exactly_the_contracts(write):  # type: ignore[no-untyped-def]
    write("typed.yaml", TYPED)
    sim = Simulation(write("plant.yaml", TYPED_PLANT), write("s.yaml", "cycles: 1\n"))
    row = next(iter(sim.run()))
    flags = ["SFCInit", "SFCReset", "SFCPause", "SFCError", "SFCEnableLimit",
             "SFCQuitError", "SFCTipMode", "SFCTip", "SFCErrorStep", "SFCCurrentStep"]
    want = {"cycle", "t_ms"}
    for i in ("a", "b"):
        want |= {f"{i}.{n}" for n in ("iGo", "iN", "oRun", "oN", "sWait", "sK", "sR", *flags)}
        want |= {f"{i}.{s}.{k}" for s in ("s0", "s1") for k in ("X", "T_ms")}
        want |= {f"{i}.ton.Q", f"{i}.ton.ET"}  # extra keys: function-block outputs
    want |= {"sim.I0", "sim.IR0", "sim.Q0", "sim.ok", "io.HR0", "io.Q0", "io.HR1", "io.ok"}
    assert set(row) == want


def test_trace_values_bools_as_0_1_times_as_whole_ms_numbers_as_they_are(
        write):  # type: ignore[no-untyped-def]
    write("typed.yaml", TYPED)
    script = write("s.yaml", "cycles: 12\nset:\n  - {at: 0ms, sim.I0: 1, a.iN: 21}\n")
    rows = list(Simulation(write("plant.yaml", TYPED_PLANT), script).run())
    r = rows[5]  # a: ton.Q at 50 ms (pre) -> s1 in that very scan (immediate)
    assert (r["a.s1.X"], r["a.oRun"], r["sim.Q0"], r["a.oN"], r["io.HR0"]) == (1, 1, 1, 42, 42)
    assert r["a.sWait"] == 1500 and r["a.sR"] == 0.5 and r["a.sK"] == 1
    assert r["a.ton.ET"] == 50 and r["a.ton.Q"] == 1
    assert r["a.SFCCurrentStep"] == "s1" and r["a.SFCErrorStep"] == ""
    assert rows[4]["a.ton.ET"] == 40 and rows[4]["a.s1.X"] == 0
    # b reads a's outputs of this cycle (a is scanned first): its TON starts at 50 ms
    assert r["b.iGo"] == 1 and r["b.iN"] == 42 and r["b.ton.ET"] == 0
    assert rows[9]["b.s1.X"] == 0 and rows[10]["b.s1.X"] == 1 and rows[10]["b.ton.ET"] == 50
    for row in rows:
        for k, v in row.items():
            assert isinstance(v, int | float | str) and not isinstance(v, bool), (k, v)


def test_cli_cycles_overrides_the_script_and_no_trace_writes_nothing(
        write, drawer, tmp_path):  # type: ignore[no-untyped-def]
    p, s = write("plant.yaml", PLANT), write("script.yaml", SCRIPT)
    trace = tmp_path / "t.jsonl"
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "simulate", p, "--script", s,
                        "--cycles", "5", "--trace", str(trace)], capture_output=True,
                       text=True, check=False)
    assert r.returncode == 0, r.stderr
    assert [json.loads(x)["cycle"] for x in trace.read_text().splitlines()] == [0, 1, 2, 3, 4]
    before = sorted(tmp_path.iterdir())
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "simulate", p, "--script", s],
                       capture_output=True, text=True, check=False)
    assert r.returncode == 0 and "simulated 20 scans" in r.stderr
    assert sorted(tmp_path.iterdir()) == before


def test_vcd_holds_the_trace_values_at_their_times(write, drawer):  # type: ignore
    import io

    from runtime.engine.simulate import write_vcd

    rows = list(Simulation(write("plant.yaml", PLANT), write("script.yaml", SCRIPT)).run())
    buf = io.StringIO()
    write_vcd(rows, buf)
    ids: dict[str, str] = {}
    values: dict[str, dict[int, str]] = {}
    t = -1
    for line in buf.getvalue().splitlines():
        parts = line.split()
        if parts[0] == "$var":
            ids[parts[4]] = parts[3]
        elif line.startswith("#"):
            t = int(line[1:])
        elif t >= 0:
            if line[0] in "bsr":
                value, code = parts[0][1:], parts[1]
            else:
                value, code = line[0], line[1:]
            values.setdefault(code, {})[t] = value
    for key in ("t1.gsAbrir.X", "t1.sCierres", "sim.Q0", "t1.SFCCurrentStep"):
        code, last = ids[key], None
        for row in rows:
            if row["t_ms"] in values[code]:
                last = values[code][row["t_ms"]]
            v = row[key]
            want = format(v, "b") if key == "t1.sCierres" else str(v) if not isinstance(
                v, str) else (v or "-")
            assert last == want, (key, row["t_ms"], last, want)


@pytest.mark.parametrize("chart, words", [
    ("""\
    grafcet: U
    scan: stable
    inputs: [go]
    steps:
      a: {initial: true}
      b: {}
    transitions:
      - {from: a, to: b, when: go}
      - {from: b, to: a, when: go}
    """, ["in cycle 2 (t = 20 ms)", "unstable chart U", "cycle of steps a, b"]),
    ("""\
    grafcet: U
    inputs: [go]
    memory: {n: 0, d: 0}
    steps:
      a: {initial: true, actions: ["N n := 10 / d"]}
      b: {}
    transitions:
      - {from: a, to: b, when: go}
    """, ["in cycle 0 (t = 0 ms)", "ZeroDivisionError"]),
])
def test_a_fault_in_a_scan_is_one_line_at_the_instance_and_exit_2(
        write, chart, words):  # type: ignore[no-untyped-def]
    write("u.yaml", chart)
    plant = write("plant.yaml", """\
    drivers: {sim: {type: sim}}
    instances:
      other: {grafcet: drawer_like.yaml, inputs: {go: sim.I1}}
      u: {grafcet: u.yaml, inputs: {go: sim.I0}}
    """)
    write("drawer_like.yaml", "grafcet: D\ninputs: [go]\nsteps:\n  s: {initial: true}\n")
    script = write("s.yaml", "cycles: 5\nset:\n  - {at: 20ms, u.go: 1}\n")
    r = subprocess.run([sys.executable, "-m", "runtime.cli", "simulate", plant, "--script",
                        script], capture_output=True, text=True, check=False)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    (line,) = [x for x in r.stderr.splitlines() if ": error: " in x]
    assert line.startswith(f"{plant}:4:3: error: expected every scan to end normally, found a "
                           "fault in the scan of instance 'u'")
    for w in words:
        assert w in line
