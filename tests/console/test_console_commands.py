"""Every command of console.md over the serial console (a real pty), with its error paths."""

from __future__ import annotations

import json
import re

from runtime.console.protocol import HELP, MAX_CYCLE
from tests.console.consolekit import Rig, wait_for


def start_t1(rig: Rig) -> None:
    """Press the start button of tester 1 (stop button released): it opens the drawer."""
    rig.set_input("I1", 1)
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 in gsAbrir")


def test_help_lists_every_command_of_the_spec(rig: Rig) -> None:
    s = rig.serial()
    out = s.ok("help")
    spec = ("help status stats get watch trace why set force unforce pause resume cycle "
            "init reset iocheck ack reload unlock lock json").split()
    spec.append("web")  # softplc web's own (docs/web.md), beyond the spec's list
    assert [line.split()[0] for line in out[:len(spec)]] == list(HELP) and set(spec) == set(HELP)
    assert s.ok("help cycle")[0].startswith("cycle    cycle [N]")
    assert s.error("help nope") == "no command 'nope'"


def test_status_text(rig: Rig) -> None:
    start_t1(rig)
    out = rig.serial().ok("status")
    assert out[0] == "state running"
    assert re.fullmatch(r"cycle time 10 ms, scans \d+, uptime \d+\.\d s", out[1])
    assert out[2:] == ["t1: gsAbrir", "t2: gsParado"]


def test_status_json(rig: Rig) -> None:
    s = rig.serial()
    s.cmd("json on")
    st = s.jcmd("status")
    assert st["ok"] is True and st["state"] == "running" and st["fault"] is None
    assert st["cycle_ms"] == 10.0 and st["scans"] > 0 and st["uptime_s"] >= 0
    assert st["steps"] == {"t1": ["gsParado"], "t2": ["gsParado"]}
    assert st["forced"] == {} and st["faults"] == [] and st["text"][0] == "state running"


def test_status_shows_paused_iocheck_halted_and_fault_with_its_reason(rig: Rig) -> None:
    s = rig.serial()
    s.ok("pause")
    assert s.ok("status")[0] == "state paused"
    s.ok("resume")
    s.ok("iocheck on")
    assert s.ok("status")[0] == "state iocheck"
    s.ok("iocheck off")
    assert s.ok("status")[0].startswith("state halted (iocheck ended")
    s.ok("ack")
    rig.driver.broken = "remote I/O not answering"
    wait_for(lambda: rig.state() == "fault", "the fault")
    out = s.ok("status")
    assert out[0] == "state fault (driver rio: remote I/O not answering)"
    assert re.fullmatch(r"fault at \d{4}-\d\d-\d\d \d\d:\d\d:\d\d: driver rio: remote I/O "
                        r"not answering", out[-1])


def test_stats_is_a_readable_table(rig: Rig) -> None:
    s = rig.serial()
    out = s.ok("stats")
    assert re.fullmatch(r"cycle time 10 ms: \d+ cycles, \d+ overruns, \d+ deadlines skipped",
                        out[0])
    assert out[1].split() == ["(us)", "last", "min", "mean", "p50", "p99", "max"]
    for row, label in zip(out[2:4], ("scan", "lateness"), strict=True):
        words = row.split()
        assert words[0] == label and len(words) == 7
        assert all(float(w) >= 0 for w in words[1:])
    assert out[4].startswith("gc ")
    assert out[5] == "driver rio: ok (on_fault stop)"
    assert not any("{" in line for line in out)  # no Python reprs
    s.cmd("json on")
    st = s.jcmd("stats")["stats"]
    assert st["lateness_us"]["p99"] >= 0 and st["drivers"]["rio"]["health"] == "ok"


def test_get_values_names_and_errors(rig: Rig) -> None:
    start_t1(rig)
    s = rig.serial()
    assert s.ok("get t1.oAbrir t1.gsAbrir.X t1.SFCPause rio.Q0") == [
        "t1.oAbrir=1  -> rio.Q0", 't1.gsAbrir.X=1  "Opening the drawer"',
        't1.SFCPause=0  "while true: the chart is paused (no transition fires)"',
        "rio.Q0=1"]
    (line,) = s.ok("get t1.gsAbrir.T")
    assert re.fullmatch(r't1\.gsAbrir\.T=(\d+s)?(\d+ms)?  "Opening the drawer"', line), line
    # the physical stop button (NC, released = 1) and what the chart sees
    assert s.ok("get rio.I0") == ["rio.I0=1  t1.iParo=0 inverted"]
    inst = s.ok("get t1")
    assert [x.split("=")[0] for x in inst] == [
        "t1.iParo", "t1.iMarcha", "t1.iAbierto", "t1.iCerrado", "t1.oAbrir", "t1.oCerrar",
        "t1.oParado", "t1.oTest", "t1.sParo", "t1.sCierres"]
    assert inst[0] == "t1.iParo=0  <- rio.I0 inverted"
    assert len(s.ok("get rio")) == 17  # 8 inputs, 8 outputs, rio.ok
    assert s.error("get t1.iMarcah") == ("unknown name 't1.iMarcah' (did you mean "
                                         "'t1.iMarcha'?)")
    assert s.error("get nothing.here") == "unknown name 'nothing.here'"
    assert s.error("get") == "usage: get NAME..."
    s.cmd("json on")
    got = s.jcmd("get t1.gsAbrir.T t1.oAbrir")
    assert isinstance(got["values"]["t1.gsAbrir.T"], int)  # ms in JSON
    assert got["values"]["t1.oAbrir"] == 1 and got["roles"]["t1.oAbrir"] == "output"


def test_watch_streams_changes_until_the_next_line(rig: Rig) -> None:
    s = rig.serial()
    assert s.ok("watch t1.iMarcha t1.gsAbrir.X") == [
        "watching 2 value(s) on every change until the next line"]
    assert s.line() == "watch: t1.iMarcha=0  t1.gsAbrir.X=0"
    rig.set_input("I1", 1)
    lines = s.until(lambda x: "t1.gsAbrir.X=1" in x)
    assert re.fullmatch(r"watch \d+: t1\.iMarcha=1  t1\.gsAbrir\.X=1", lines[-1])
    assert all(x.startswith("watch") for x in lines)
    assert s.cmd("status")[-1] == "ok"  # any new line ends the stream
    assert s.error("watch t1.nope").startswith("unknown name 't1.nope'")
    assert s.error("watch t1.iMarcha every fast") == ("bad value 'fast' after 'every': "
                                                      "expected a number of ms")


def test_watch_every_period_repeats_the_values(rig: Rig) -> None:
    s = rig.serial()
    assert s.ok("watch rio.Q2 every 50") == ["watching 1 value(s) every 50 ms until the next "
                                             "line"]
    lines = [s.line() for _ in range(4)]
    assert lines[0] == "watch: rio.Q2=1"
    assert all(re.fullmatch(r"watch \d+: rio\.Q2=1", x) for x in lines[1:])
    s.send(b"\r")


def test_trace_streams_one_line_per_scan_of_changes(rig: Rig) -> None:
    s = rig.serial()
    assert s.ok("trace on") == ["tracing every scan's changes until the next line"]
    rig.set_input("I1", 1)
    lines = s.until(lambda x: "t1.gsAbrir.X=1" in x)
    line = lines[-1]
    assert re.match(r"trace \d+: ", line)
    for part in ("t1.iMarcha=1", "t1.gsParado.X=0", "t1.oAbrir=1", "rio.Q0=1", "rio.Q3=1"):
        assert part in line.split(": ", 1)[1].split("  "), line
    assert ".T=" not in line  # step times change every scan: not traced
    assert s.ok("trace off") == []
    s.cmd("json on")
    s.cmd("trace on")
    rig.set_input("I2", 1)  # drawer open: t1 goes on to gsCerrar
    obj = json.loads(s.until(lambda x: "gsCerrar.X" in x)[-1])
    assert obj["trace"]["t1.gsCerrar.X"] == 1 and isinstance(obj["scan"], int)
    assert json.loads(s.cmd("trace maybe")[0])["error"] == "usage: trace on|off"


def test_why_explains_each_transition_with_its_terms(rig: Rig) -> None:
    start_t1(rig)
    s = rig.serial()
    out = s.ok("why t1")
    assert re.fullmatch(r'gsAbrir active for (\d+s)?(\d+ms)?  "Opening the drawer"',
                        out[0]), out[0]
    assert "us" not in out[0] and "ns" not in out[0]
    assert out[1:] == ["  [false] gsAbrir -> gsCerrar when iAbierto",
                       "      iAbierto = 0",
                       "  [false] gsAbrir -> gsAveria when tAveriaAbrir",
                       "      tAveriaAbrir = 0"]
    s.ok("force t1.SFCPause 1")
    s.ok("force t1.iAbierto 1")
    out = s.ok("why t1")
    assert "  [blocked] gsAbrir -> gsCerrar when iAbierto" in out
    assert "      blocked by: chart paused (SFCPause/SFCQuitError)" in out
    assert "      iAbierto = 1" in out
    s.ok("unforce t1.SFCPause")
    # released, a variable nobody writes keeps its last value (as in CODESYS)
    assert rig.read("t1.SFCPause") is True and rig.steps("t1") == ["gsAbrir"]
    s.ok("set t1.SFCPause 0")
    wait_for(lambda: rig.steps("t1") == ["gsCerrar"], "t1 in gsCerrar")
    assert s.error("why t3") == "usage: why INSTANCE; no instance 't3' (one of t1 t2)"
    s.cmd("json on")
    why = s.jcmd("why t1")["why"]
    assert why[0]["step"] == "gsCerrar" and isinstance(why[0]["time_ms"], int)
    assert why[0]["transitions"][0]["terms"][0]["text"] == "tParo"


def test_set_writes_once_and_refuses_what_would_be_overwritten(rig: Rig) -> None:
    s = rig.serial()
    assert s.ok("set t1.sCierres 41") == ["t1.sCierres set to 41"]
    assert rig.read("t1.sCierres") == 41
    assert s.error("set t1.sCierres lots") == ("bad value 'lots' for t1.sCierres: expected "
                                              "an integer")
    assert s.error("set t1.sParo 2") == ("bad value '2' for t1.sParo: expected 0 or 1 (or "
                                        "true/false, on/off)")
    assert s.error("set t1.nope 1").startswith("unknown name 't1.nope'")
    assert s.error("set t1.sParo") == "usage: set NAME VALUE"
    assert s.error("set t1.iMarcha 1") == ("t1.iMarcha is copied from rio.I1 before every "
                                          "scan: set that point, or force t1.iMarcha")
    assert s.error("set rio.Q0 1") == ("rio.Q0 is written by t1.oAbrir every scan: force it, "
                                      "or pause or 'iocheck on' first")
    assert s.error("set t1.gsAbrir.X 1") == "'t1.gsAbrir.X' cannot be written"
    assert s.ok("set rio.I1 1") == ["rio.I1 set to 1"]  # simulated I/O: the button
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 started")


def test_set_refuses_what_the_chart_writes_every_scan(rig: Rig) -> None:
    """A chart output is computed by its chart every scan (its action control): a ``set``
    of it was answered "set to 1" and never reached the output (the page's ``set
    tester1.oAbrir 1``). Refused, paused or not (a held chart's outputs are not copied to
    their points either: only a force is), as is a variable assigned at the top of
    ``pre``; a memory variable the chart writes only in some steps is set as before."""
    s = rig.serial()
    assert s.error("set t1.oAbrir 1") == ("t1.oAbrir is written by its chart every scan: "
                                         "force it")
    assert s.error("set t1.tParo 1") == "t1.tParo is written by its chart every scan: force it"
    assert s.ok("set t1.sCierres 3") == ["t1.sCierres set to 3"]
    s.ok("pause")
    assert s.error("set t1.oAbrir 1") == ("t1.oAbrir is written by its chart every scan: "
                                         "force it")
    s.ok("resume")
    assert rig.read("t1.oAbrir") is False and rig.read("rio.Q0") is False


def test_force_wins_over_drivers_and_program_and_is_listed(rig: Rig) -> None:
    start_t1(rig)
    s = rig.serial()
    # a forced chart input wins over its driver
    assert s.ok("force t1.iAbierto 1") == ["t1.iAbierto forced to 1"]
    wait_for(lambda: rig.steps("t1") == ["gsCerrar"], "t1 closing")
    assert rig.driver.inputs["I2"] == 0
    # a forced physical output wins over the program (t1 drives oCerrar -> rio.Q1)
    s.ok("force rio.Q1 0")
    rig.daemon.call(lambda: None)
    rig.daemon.call(lambda: None)
    assert rig.read("t1.oCerrar") is True and rig.driver.outputs["Q1"] == 0
    # a forced physical input masks the driver's value
    s.ok("force rio.I7 1")
    wait_for(lambda: rig.read("t2.iCerrado") is True, "t2.iCerrado from the forced point")
    assert s.ok("get rio.I7 t1.iAbierto") == [
        "rio.I7=1 (forced; the driver reads 0)  t2.iCerrado=1",
        "t1.iAbierto=1 (forced)  <- rio.I2"]
    status = s.ok("status")
    assert status[-4:] == ["forced t1.iAbierto=1", "forced rio.Q1=0", "forced rio.I7=1",
                           # the forced point holds what the chart does not say
                           "not applied: t1.oCerrar: the chart's 1, rio.Q1 holds 0"]
    assert s.ok("unforce rio.Q1") == ["rio.Q1 released"]
    wait_for(lambda: rig.driver.outputs["Q1"] == 1, "rio.Q1 back to the program")
    assert s.error("unforce rio.Q1") == "'rio.Q1' is not forced"
    assert s.ok("unforce all") == ["released t1.iAbierto, rio.I7"]
    assert not rig.plant.forced and not rig.plant.forced_points
    assert s.ok("unforce all") == ["nothing was forced"]
    assert s.error("force t1.gsAbrir.X 1").startswith("t1.gsAbrir.X cannot be forced")
    assert s.error("force t1.iAbierto maybe").startswith("bad value 'maybe' for t1.iAbierto")
    assert s.error("force t9.x 1").startswith("unknown name 't9.x'")
    assert s.error("unforce") == "usage: unforce NAME|all"


def test_forced_chart_output_reaches_its_point_while_paused(rig: Rig) -> None:
    s = rig.serial()
    s.ok("pause")
    s.ok("force t1.oTest 1")
    wait_for(lambda: rig.driver.outputs["Q3"] == 1, "rio.Q3 from the forced t1.oTest")


def test_pause_holds_the_charts_and_resume_goes_on(rig: Rig) -> None:
    s = rig.serial()
    assert s.ok("pause")[0].startswith("paused: charts hold, I/O still scanned")
    assert s.ok("pause")[0].startswith("already paused")
    rig.set_input("I1", 1)
    scans = rig.daemon.scan_stats.count
    wait_for(lambda: rig.daemon.scan_stats.count > scans + 3, "a few cycles")
    assert rig.steps("t1") == ["gsParado"]
    assert rig.read("t1.iMarcha") is False  # not even copied: the chart does not scan
    assert s.ok("get rio.I1") == ["rio.I1=1  t1.iMarcha=1"]  # but the I/O is read
    assert s.ok("resume") == ["resumed"]
    wait_for(lambda: rig.steps("t1") == ["gsAbrir"], "t1 started")
    assert s.ok("resume") == ["not paused"]


def test_cycle_runs_exact_scans_and_reports_what_changed(rig: Rig) -> None:
    s = rig.serial()
    assert s.error("cycle") == "cycle runs while paused; the controller is running: pause first"
    s.ok("pause")
    rig.set_input("I1", 1)
    out = s.ok("cycle")
    assert re.fullmatch(r"ran 1 scan\(s\) \((\d+)\.\.\1\)", out[0]), out
    assert re.fullmatch(r"scan \d+: t1 gsParado -> gsAbrir; .*", out[1]), out
    for change in ("t1.iMarcha 0 -> 1", "t1.oAbrir 0 -> 1", "rio.Q0 0 -> 1",
                   "t1.SFCCurrentStep gsParado -> gsAbrir"):
        assert change in out[1]
    assert len(out) == 2
    assert rig.state() == "paused" and rig.steps("t1") == ["gsAbrir"]
    assert s.ok("cycle 3")[1:] == ["nothing changed"]
    rig.set_input("I2", 1)
    s.cmd("json on")
    rep = s.jcmd("cycle 2")
    assert rep["scans"] == 2 and len(rep["per_scan"]) == 2
    assert rep["changed"]["t1.gsCerrar.X"] == 1 and rep["changed"]["t1.gsAbrir.X"] == 0
    s.cmd("json off")
    assert s.error("cycle 0") == f"bad value 0: cycle N runs 1 to {MAX_CYCLE} scans"
    assert s.error(f"cycle {MAX_CYCLE + 1}").startswith("bad value")
    assert s.error("cycle many") == "bad value 'many': expected a number of scans"
    assert s.error("cycle 1 2") == "usage: cycle [N]"


def test_init_and_reset_pulse_for_one_scan(rig: Rig) -> None:
    start_t1(rig)
    s = rig.serial()
    assert s.ok("reset t1") == ["SFCReset pulsed on t1 at the next scan"]
    wait_for(lambda: rig.steps("t1") == ["gsParado"], "t1 back in its initial step")
    assert rig.read("t1.SFCReset") is False  # a pulse, not a level
    s.ok("pause")
    assert s.ok("init t2") == ["SFCInit pulsed on t2 at the next scan ('cycle' or 'resume': "
                               "paused now)"]
    out = s.ok("cycle")
    assert rig.read("t2.SFCInit") is False and rig.steps("t2") == ["gsParado"]
    assert "t2.SFCInit" not in " ".join(out)  # set and cleared within the scan
    assert s.error("reset t9") == "usage: reset INSTANCE; no instance 't9' (one of t1 t2)"
    assert s.error("init") == "usage: init INSTANCE (one of t1 t2)"


def test_ack_of_a_fault_once_its_cause_is_gone(rig: Rig) -> None:
    s = rig.serial()
    assert s.error("ack") == "nothing to acknowledge"
    start_t1(rig)
    rig.driver.broken = "bus cable cut"
    wait_for(lambda: rig.state() == "fault", "the fault")
    assert rig.driver.outputs["Q0"] == 0
    assert s.error("ack") == "the fault is still there: driver rio: bus cable cut"
    rig.driver.broken = None
    wait_for(lambda: rig.daemon.call(lambda: rig.plant.faulted()) is None, "the bus back",
             timeout=30)
    assert s.ok("ack") == ["fault acknowledged: charts restarted from their initial situation"]
    assert rig.state() == "running" and rig.steps("t1") == ["gsParado"]


def test_json_mode_one_object_per_line(rig: Rig) -> None:
    s = rig.serial()
    assert s.cmd("json on") == ['{"ok": true, "text": []}']
    for cmd in ("help", "status", "stats", "get t1", "why t1", "nope", "get t1.x",
                "set t1.sParo 5"):
        out = s.cmd(cmd)
        assert len(out) == 1, out
        obj = json.loads(out[0])
        assert obj["ok"] is (cmd not in ("nope", "get t1.x", "set t1.sParo 5"))
        if not obj["ok"]:
            assert obj["error"] and set(obj) == {"ok", "error"}
    assert json.loads(s.cmd(b"\xff")[0]) == {"ok": False,
                                            "error": "line is not valid UTF-8: ignored"}
    assert json.loads(s.cmd("json maybe")[0])["error"] == "usage: json on|off"
    s.cmd("watch rio.I1")
    obj = json.loads(s.line())
    assert obj == {"watch": {"rio.I1": 0}, "logical": {"t1.iMarcha": 0}}
    assert s.cmd("json off") == ["ok"]
    assert s.cmd("status")[0] == "state running"
