"""Bench wiring (iocheck): charts stopped, outputs off, one output at a time, physical and
logical inputs side by side, and no restart before ``ack``."""

from __future__ import annotations

import re

from tests.console.consolekit import Rig, wait_for


def outputs(rig: Rig) -> dict[str, int]:
    return dict(rig.daemon.call(lambda: dict(rig.driver.outputs)))


def test_iocheck_procedure(rig: Rig) -> None:
    s = rig.serial()
    rig.set_input("I1", 1)
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 opening the drawer")
    assert outputs(rig)["Q0"] == 1 and outputs(rig)["Q3"] == 1
    s.ok("force t2.iMarcha 1")
    out = s.ok("iocheck on")
    assert out[0].startswith("iocheck: charts stopped, every output off")
    assert out[1] == "released forces: t2.iMarcha"
    assert not rig.plant.forced
    assert rig.state() == "iocheck"
    assert set(outputs(rig).values()) == {0}
    # the charts are stopped: inputs change, steps do not
    rig.set_input("I2", 1)
    scans = rig.daemon.scan_stats.count
    wait_for(lambda: rig.daemon.scan_stats.count > scans + 3, "a few cycles")
    assert rig.steps("t1") == ["gsAbrir"] and set(outputs(rig).values()) == {0}
    # one output at a time
    assert s.ok("set rio.Q3 1") == ["rio.Q3 set to 1"]
    wait_for(lambda: outputs(rig)["Q3"] == 1, "rio.Q3 on")
    assert [p for p, v in outputs(rig).items() if v] == ["Q3"]
    s.ok("set rio.Q3 0")
    s.ok("set rio.Q5 1")
    wait_for(lambda: [p for p, v in outputs(rig).items() if v] == ["Q5"], "only rio.Q5 on")
    # physical inputs with their logical value, the NC stop buttons shown inverted
    assert s.ok("watch") == ["watching 8 value(s) on every change until the next line"]
    first = s.line()
    assert first.startswith("watch: rio.I0=1 (t1.iParo=0 inverted)  rio.I1=1 (t1.iMarcha=1)")
    assert "rio.I4=1 (t2.iParo=0 inverted)" in first
    rig.set_input("I0", 0)  # the technician presses stop button SJP of bench 1
    line = s.until(lambda x: "rio.I0=0" in x)[-1]
    assert re.match(r"watch \d+: rio\.I0=0 \(t1\.iParo=1 inverted\)", line)
    rig.set_input("I0", 1)
    s.until(lambda x: "rio.I0=1" in x)
    # leaving: every output off, charts stopped until ack
    assert s.ok("iocheck off") == ["iocheck off: every output off; 'ack' restarts the charts "
                                   "from their initial situation"]
    assert set(outputs(rig).values()) == {0}
    assert s.ok("status")[0] == ("state halted (iocheck ended: 'ack' restarts the charts from "
                                 "their initial situation)")
    scans = rig.daemon.scan_stats.count
    wait_for(lambda: rig.daemon.scan_stats.count > scans + 3, "a few cycles")
    assert rig.steps("t1") == ["gsAbrir"] and set(outputs(rig).values()) == {0}
    assert s.error("set rio.Q3 1") == "the controller is halted: outputs are held off until 'ack'"
    assert s.error("iocheck off") == "not in iocheck"
    assert s.ok("ack") == ["charts restarted from their initial situation"]
    assert rig.state() == "running"
    # from the initial situation: gsParado, then the start button held since before is no
    # rising edge, so the tester stays stopped
    wait_for(lambda: outputs(rig)["Q2"] == 1, "pilot 'stopped' on")
    assert rig.steps("t1") == ["gsParado"] and outputs(rig)["Q0"] == 0


def test_iocheck_again_from_the_halt_and_errors(rig: Rig) -> None:
    s = rig.serial()
    s.ok("iocheck on")
    assert s.ok("iocheck on")[0].startswith("iocheck: charts stopped")  # idempotent
    assert s.error("pause") == "iocheck on: the charts are stopped already"
    assert s.error("init t1") == "iocheck on: the charts are stopped"
    assert s.error("cycle") == "cycle runs while paused; the controller is iocheck"
    assert s.error("iocheck maybe") == "usage: iocheck on|off"
    s.ok("iocheck off")
    # back to the bench without letting the charts run in between
    s.ok("iocheck on")
    assert rig.state() == "iocheck"
    s.ok("set rio.Q1 1")
    wait_for(lambda: outputs(rig)["Q1"] == 1, "rio.Q1 on")
    s.ok("iocheck off")
    s.ok("ack")
    assert rig.state() == "running"


def test_iocheck_refused_in_fault(rig: Rig) -> None:
    s = rig.serial()
    rig.driver.broken = "no power on the I/O"
    wait_for(lambda: rig.state() == "fault", "the fault")
    assert s.error("iocheck on") == "the controller is in fault: 'ack' it first"
