"""``softplc simulate`` keeps its word: ``--cycles`` overrides a script without a length,
and a scan that faults leaves a trace of every scan before it and a last record naming
the fault (issue 13 §5)."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.engine.simulate import ScanFault, Simulation
from runtime.errors import SourceError

Write = Callable[[str, str], str]

PLANT = """\
plc: {cycle: 10ms}
drivers: {sim: {type: sim}}
instances:
  u: {grafcet: u.yaml, inputs: {go: sim.I0}, outputs: {oRun: sim.Q0}}
"""

#: counts its scans in n; from the scan where `go` is seen, divides by zero
CHART = """\
grafcet: U
inputs: [go]
outputs: [oRun]
memory: {n: 0, d: 0}
steps:
  a: {initial: true, actions: [oRun, "N n := n + 1"]}
  b: {actions: ["N n := 10 / d"]}
transitions:
  - {from: a, to: b, when: go}
"""


def simulate(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "runtime.cli", "simulate", *args],
                          capture_output=True, text=True, timeout=120, check=False)


@pytest.fixture
def plant(write: Write) -> str:
    write("u.yaml", CHART)
    return write("plant.yaml", PLANT)


def test_cycles_overrides_a_script_without_duration(write: Write, plant: str,
                                                    tmp_path: Path) -> None:
    script = write("s.yaml", "set:\n  - {at: 1s, u.go: 1}\n")  # no duration:, no cycles:
    trace = tmp_path / "t.jsonl"
    r = simulate(plant, "--script", script, "--cycles", "7", "--trace", str(trace))
    assert r.returncode == 0, r.stderr
    assert "simulated 7 scans" in r.stderr
    rows = [json.loads(x) for x in trace.read_text().splitlines()]
    assert [x["cycle"] for x in rows] == list(range(7))
    assert [x["u.n"] for x in rows] == list(range(1, 8))


def test_a_script_without_length_needs_cycles_one_line_at_the_script(
        write: Write, plant: str) -> None:
    script = write("s.yaml", "set:\n  - {at: 1s, u.go: 1}\n")
    with pytest.raises(SourceError) as e:
        Simulation(plant, script)
    assert e.value.loc.file == script and e.value.loc.line == 1
    r = simulate(plant, "--script", script)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.splitlines() == [
        f"{script}:1:1: error: the script needs 'duration:' or 'cycles:' (or give --cycles N)"]


def test_the_script_length_still_counts_without_cycles(write: Write, plant: str) -> None:
    script = write("s.yaml", "duration: 55ms\n")
    assert Simulation(plant, script).cycles == 6
    assert Simulation(plant, script, cycles=2).cycles == 2


def test_a_faulting_scan_keeps_the_trace_before_it_and_names_the_fault(
        write: Write, plant: str, tmp_path: Path) -> None:
    script = write("s.yaml", "cycles: 10\nset:\n  - {at: 40ms, u.go: 1}\n")
    trace, vcd = tmp_path / "t.jsonl", tmp_path / "t.vcd"
    r = simulate(plant, "--script", script, "--trace", str(trace), "--vcd", str(vcd))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    (line,) = r.stderr.splitlines()
    assert line.startswith(f"{plant}:4:3: error: expected every scan to end normally, found a "
                           "fault in the scan of instance 'u' (grafcet U")
    assert "in cycle 4 (t = 40 ms): ZeroDivisionError" in line
    rows = [json.loads(x) for x in trace.read_text().splitlines()]
    # every scan before the fault, as a run without the fault would have traced them
    assert [x["cycle"] for x in rows] == [0, 1, 2, 3, 4]
    assert [x["u.n"] for x in rows[:4]] == [1, 2, 3, 4]
    assert all(x["sim.Q0"] == 1 and "fault" not in x for x in rows[:4])
    last = rows[-1]
    assert last["t_ms"] == 40 and last["instance"] == "u"
    assert last["fault"] == line.split(": error: ", 1)[1]
    # the physical image at the fault: inputs as read, every output off (safe state)
    assert last["sim.I0"] == 1 and last["sim.Q0"] == 0 and last["sim.ok"] == 1
    assert not any(k.startswith("u.") for k in last)  # the faulted scan's values are not
    text = vcd.read_text()
    assert "$var string" in text and " fault $end" in text
    assert "#40\n" in text and "ZeroDivisionError" in text.split("#40\n", 1)[1]


def test_a_fault_without_trace_is_the_same_line(write: Write, plant: str) -> None:
    script = write("s.yaml", "cycles: 10\nset:\n  - {at: 40ms, u.go: 1}\n")
    sim = Simulation(plant, script)
    with pytest.raises(ScanFault) as e:
        for _ in sim.run(trace=False):
            pass
    assert "in cycle 4 (t = 40 ms)" in str(e.value)
    sim = Simulation(plant, script)
    rows: list[dict[str, object]] = []
    with pytest.raises(ScanFault):
        for row in sim.run():
            rows.append(row)
    assert len(rows) == 5 and rows[-1]["fault"] == e.value.message


def test_a_script_given_as_a_second_file_points_at_script(write: Write, plant: str) -> None:
    """``softplc simulate PLANT story.yaml``: the simulate command's usage and where the
    script goes (it printed the top-level usage, naming every command but this one's
    options)."""
    script = write("story.yaml", "set:\n  - {at: 1s, u.go: 1}\n")
    r = simulate(plant, script)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert r.stderr.startswith("usage: softplc simulate "), r.stderr
    assert r.stderr.splitlines()[-1] == (
        f"softplc simulate: error: unrecognized arguments: {script} (a script is given "
        f"with --script: --script {script})"), r.stderr
