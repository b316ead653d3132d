"""``softplc check`` on plant files: bindings (G301, G302) and driver points (G303-G305)."""

from __future__ import annotations

import argparse
from collections.abc import Callable

import pytest

from runtime.checker.check import check_files, exit_status, register

CHART = """\
grafcet: Small
inputs: [iA, iB]
outputs: [oX, oY]
steps:
  gsA: {initial: true}
  gsB: {actions: [oX, oY]}
transitions:
  - {from: gsA, to: gsB, when: iA}
  - {from: gsB, to: gsA, when: "iA'·iB"}
"""


@pytest.fixture
def chart(write: Callable[[str, str], str]) -> str:
    return write("small.yaml", CHART)


def diags_of(write: Callable[[str, str], str], text: str) -> tuple[list[str], int]:
    path = write("plant.yaml", text)
    res = check_files([path])
    assert not any(r.failure for r in res), [r.failure for r in res]
    return [f"{d.severity} {d.code} {d.line}" for r in res for d in r.diags], exit_status(res)


def test_clean_plant(write: Callable[[str, str], str], chart: str) -> None:
    found, status = diags_of(write, """\
        drivers:
          sim: {type: sim}
          exp1: {type: mcp23017, bus: 1, address: 0x20}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: exp1.A0, iB: {from: exp1.A1, invert: true}}
            outputs: {oX: exp1.B0, oY: sim.Q0}
        """)
    assert status == 0 and not [f for f in found if f.startswith("error")], found


def test_g301_every_unbound_signal(write: Callable[[str, str], str], chart: str) -> None:
    found, status = diags_of(write, """\
        drivers:
          sim: {type: sim}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: sim.I0}
            outputs: {oX: sim.Q0}
          b:
            grafcet: small.yaml
            outputs: {oX: sim.Q1, oY: sim.Q2}
        """)
    assert status == 2  # an error: 2, whoever finds it
    g301 = [f for f in found if " G301 " in f]
    assert len(g301) == 4, found  # a.iB, a.oY, b.iA, b.iB


def test_g302_output_bound_twice(write: Callable[[str, str], str], chart: str) -> None:
    found, status = diags_of(write, """\
        drivers:
          sim: {type: sim}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.Q0, oY: sim.Q1}
          b:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.Q2, oY: {from: sim.Q1}}
        """)
    assert status == 2  # an error: 2, whoever finds it
    assert "error G302 11" in found, found
    # near miss: both instances read the same input points, which is fine
    assert [f for f in found if " G302 " in f] == ["error G302 11"], found


def test_g303_points_that_do_not_exist(write: Callable[[str, str], str], chart: str) -> None:
    found, status = diags_of(write, """\
        drivers:
          exp1: {type: mcp23017, bus: 1, address: 0x20}
          mb: {type: modbus_rtu, port: /dev/null, unit: 1}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: exp1.C0, iB: mb.I0}
            outputs: {oX: mb.I3, oY: exp1.ok}
        """)
    assert status == 2  # an error: 2, whoever finds it
    assert found.count("error G303 7") == 1, found  # exp1.C0
    assert found.count("error G303 8") == 2, found  # mb.I3 read-only, exp1.ok as output


def test_bad_driver_config_is_a_loading_error(write: Callable[[str, str], str],
                                              chart: str) -> None:
    """The plant loader refuses it (as compile and run do): one line, exit status 2."""
    path = write("plant.yaml", """\
        drivers:
          exp1: {type: mcp23017, bus: 1, address: 300}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: exp1.A0, iB: exp1.A1}
            outputs: {oX: exp1.B0, oY: exp1.B1}
        """)
    res = check_files([path])
    assert exit_status(res) == 2
    assert [r.failure for r in res] == [f"{path}:2:43: error: driver exp1 (mcp23017): address: "
                                        "expected an MCP23017 address from 0x20 to 0x27 (pins "
                                        "A2 A1 A0), found 300"]


def test_g305_missing_driver_library(write: Callable[[str, str], str], chart: str,
                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.registry as reg

    real = reg.driver_class

    def fake(type_name: str):  # type: ignore[no-untyped-def]
        if type_name == "mcp23017":
            raise reg.DriverImportError("driver type 'mcp23017' needs the Python package "
                                        "'smbus2': pip install smbus2")
        return real(type_name)

    monkeypatch.setattr(reg, "driver_class", fake)
    found, status = diags_of(write, """\
        drivers:
          exp1: {type: mcp23017, bus: 1, address: 0x20}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: exp1.A0, iB: exp1.A1}
            outputs: {oX: exp1.B0, oY: exp1.B1}
        """)
    assert status == 0
    assert found == ["note G305 6"], found
    # the point names are checked all the same, from the type's description (no library)
    found, status = diags_of(write, """\
        drivers:
          exp1: {type: mcp23017, bus: 1, address: 0x20}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: exp1.Z9, iB: exp1.A1}
            outputs: {oX: exp1.B0, oY: exp1.B1}
        """)
    assert status == 2  # an error: 2, whoever finds it
    assert found == ["error G303 6"], found


def test_g306_one_input_point_feeds_two_inputs_of_an_instance(
        write: Callable[[str, str], str], chart: str) -> None:
    found, status = diags_of(write, """\
        drivers:
          sim: {type: sim}
          exp1: {type: mcp23017, bus: 1, address: 0x20}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: exp1.A2, iB: {from: exp1.A2, invert: true}}
            outputs: {oX: exp1.B0, oY: exp1.B1}
          b:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I0}
            outputs: {oX: sim.Q0, oY: sim.Q1}
        """)
    assert status == 0  # a warning
    assert [f for f in found if " G306 " in f] == ["warning G306 7", "warning G306 11"], found


def test_g306_near_miss_instances_sharing_an_input(write: Callable[[str, str], str],
                                                   chart: str) -> None:
    """A shared push-button read by two instances (each reads it once) is fine."""
    found, _ = diags_of(write, """\
        drivers: {sim: {type: sim}}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.Q0, oY: sim.Q1}
          b:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I2}
            outputs: {oX: sim.Q2, oY: sim.Q3}
        """)
    assert not [f for f in found if f.split()[0] != "note"], found


def test_g307_output_bound_to_an_input_point(write: Callable[[str, str], str],
                                             chart: str) -> None:
    path = write("plant.yaml", """\
        drivers: {sim: {type: sim}}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.I1, oY: sim.I7}
        """)
    res = check_files([path])
    g307 = [d for r in res for d in r.diags if d.code == "G307"]
    assert [(d.severity, d.line) for d in g307] == [("warning", 6), ("warning", 6)], g307
    assert "'sim.I1' is also bound as input 'a.iB' (line 5)" in g307[0].message
    assert "'sim.I7' is named as an input point" in g307[1].message
    assert exit_status(res) == 0


def test_g307_near_miss_and_no_double_report_of_g303(write: Callable[[str, str], str],
                                                     chart: str) -> None:
    """Outputs on output points are fine; on a hardware driver a point used both ways is
    already the error G303, not also a warning."""
    found, status = diags_of(write, """\
        drivers:
          sim: {type: sim}
          exp1: {type: mcp23017, bus: 1, address: 0x20}
        instances:
          a:
            grafcet: small.yaml
            inputs: {iA: sim.I0, iB: exp1.A0}
            outputs: {oX: sim.Q0, oY: exp1.A0}
        """)
    assert status == 2  # an error: 2, whoever finds it
    assert "error G303 8" in found and not [f for f in found if " G307 " in f], found


def test_plant_checks_its_charts_once(write: Callable[[str, str], str]) -> None:
    write("bad.yaml", CHART.replace("to: gsA, when", "to: gsB, when"))
    path = write("plant.yaml", """\
        drivers: {sim: {type: sim}}
        instances:
          a:
            grafcet: bad.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.Q0, oY: sim.Q1}
          b:
            grafcet: bad.yaml
            inputs: {iA: sim.I2, iB: sim.I3}
            outputs: {oX: sim.Q2, oY: sim.Q3}
        """)
    res = check_files([path])
    assert [r.path.rsplit("/", 1)[-1] for r in res] == ["plant.yaml", "bad.yaml"]
    assert [d.code for d in res[1].diags].count("G103") == 1
    assert exit_status(res) == 2


def test_register_and_cli(write: Callable[[str, str], str], chart: str,
                          capsys: pytest.CaptureFixture[str]) -> None:
    p = argparse.ArgumentParser(prog="softplc")
    sub = p.add_subparsers(dest="command", required=True)
    register(sub)
    bad = write("bad.yaml", CHART.replace("to: gsA, when", "to: gsB, when"))
    args = p.parse_args(["check", chart, bad])
    assert args.func(args) == 2
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert len(lines) == 1 and ": error G103: " in lines[0] and lines[0].startswith(bad)
    assert "1 error(s)" in out.err
    missing = write("none.yaml", "grafcet: X\nsteps: {gsA: {initial: true}}\ntransitions:\n"
                                 "  - {from: gsA, to: gsB, when: 1}\n")
    args = p.parse_args(["check", "-q", missing])
    assert args.func(args) == 2
    assert "unknown step 'gsB'" in capsys.readouterr().out


def test_plant_whose_chart_breaks_a_rule(write: Callable[[str, str], str]) -> None:
    write("bad.yaml", CHART.replace("actions: [oX, oY]", 'actions: ["P1 oX", oY]'))
    path = write("plant.yaml", """\
        drivers: {sim: {type: sim}}
        instances:
          a:
            grafcet: bad.yaml
            inputs: {iA: sim.I0, iB: sim.I1}
            outputs: {oX: sim.Q0, oY: sim.Q1}
        """)
    res = check_files([path])
    assert exit_status(res) == 2  # the chart's rule error: an error, whoever finds it
    assert [d.code for r in res for d in r.diags] == ["G300", "G105"]
