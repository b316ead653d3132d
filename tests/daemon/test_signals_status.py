"""``status`` names every condition that keeps the charts or the outputs from running:
fault, outputs inhibited by the watchdog thread, paused, stepping, iocheck, halted, and
instances held by SFCInit, SFCReset or SFCPause; ``summary()`` (systemd's STATUS=, the
log) shows them too."""

from __future__ import annotations

from runtime.controller.daemon import Daemon
from tests.console.conftest import rig, rigs  # noqa: F401 - the console's fixtures
from tests.console.consolekit import Rig
from tests.daemon.daemonkit import MakeDaemon, wait_until


def inhibits(d: Daemon) -> list[str]:
    got: list[str] = d.status()["inhibits"]
    summary = d.summary()
    assert all(x.split(": ", 1)[-1] in summary for x in got), summary
    return got


def test_running_has_no_inhibit(make_daemon: MakeDaemon) -> None:
    d, _ = make_daemon()
    wait_until(lambda: d.scan_stats.count > 2, what="scans")
    assert inhibits(d) == []
    assert d.summary().startswith("running;")


def test_pause_stepping_iocheck_and_halted_are_named(make_daemon: MakeDaemon) -> None:
    d, _ = make_daemon()
    wait_until(lambda: d.scan_stats.count > 2, what="scans")
    d.call(d.plant.pause)
    assert inhibits(d) == ["paused by the console: charts held"]
    d.call(lambda: d.plant.step(1_000_000))
    got = inhibits(d)
    assert len(got) == 1 and got[0].startswith("stepping by the console: "), got
    assert got[0].endswith(" cycle(s) to go")
    d.call(d.plant.resume)
    assert inhibits(d) == []
    d.call(lambda: d.plant.set_iocheck(True))
    assert inhibits(d) == ["iocheck: charts stopped, outputs set by hand"]
    d.call(lambda: d.plant.set_iocheck(False))
    d.require_ack("iocheck ended")
    assert inhibits(d) == ["halted: iocheck ended (outputs off until ack)"]
    assert d.summary().startswith("halted (iocheck ended (outputs off until ack));")


def test_fault_and_the_watchdog_inhibit_are_named(make_daemon: MakeDaemon) -> None:
    d, drv = make_daemon()
    wait_until(lambda: d.scan_stats.count > 2, what="scans")
    drv.block_s = 1.0  # the next read hangs: the watchdog thread inhibits the outputs
    wait_until(lambda: drv.inhibited, what="the watchdog thread's trip")
    got = inhibits(d)
    assert "outputs inhibited by the watchdog thread" in got
    wait_until(lambda: d.fault is not None, what="the fault")
    got = inhibits(d)
    assert got[0].startswith("fault: watchdog: a scan has been running for")
    assert "outputs inhibited by the watchdog thread" in got


def test_instances_held_by_their_chart_flags_are_named(make_daemon: MakeDaemon) -> None:
    d, _ = make_daemon()
    wait_until(lambda: d.scan_stats.count > 2, what="scans")
    m = d.plant.instances["m"]
    for flag in ("SFCInit", "SFCReset", "SFCPause"):
        d.call(lambda f=flag: m.set(f, True))  # type: ignore[misc]
        assert inhibits(d) == [f"m: held by {flag}"]
        d.call(lambda f=flag: m.set(f, False))  # type: ignore[misc]
        assert inhibits(d) == []


def test_the_console_status_says_what_holds_an_instance(rig: Rig) -> None:  # noqa: F811
    s = rig.serial()
    s.ok("set t1.SFCPause 1")
    status = s.ok("status")
    assert status[0] == "state running (t1 held by SFCPause)"  # not a bare "running"
    assert "inhibit: t1: held by SFCPause" in status
    assert any(ln.startswith("t1: ") and ln.endswith(" (held by SFCPause)") for ln in status)
    s.ok("pause")
    status = s.ok("status")
    assert status[0] == "state paused"
    assert status[2:4] == ["inhibit: paused by the console: charts held",
                           "inhibit: t1: held by SFCPause"]
    s.ok("set t1.SFCPause 0")
    s.ok("resume")
    assert not [ln for ln in s.ok("status") if ln.startswith("inhibit")]
