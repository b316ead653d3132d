"""The controller's alarms (runtime/controller/alarms.py) on a running daemon: each cause
raises its condition, unacknowledged and unconfirmed; an acknowledged alarm stays active
until its cause clears; confirm after acknowledge; every change one log line; the
console's status lines say the same states."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from drivers.base import DriverError
from runtime.controller import alarms as alarms_mod
from runtime.controller.alarms import AlarmRefused, alarm_lines
from runtime.controller.daemon import Daemon
from runtime.engine.plant import Plant
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import RecordingDriver
from tests.opcua.kit import free_port, write_plant


def wait_for(pred: object, what: str, timeout: float = 15.0) -> None:
    end = time.monotonic() + timeout
    while not pred():  # type: ignore[operator]
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


def state(d: Daemon, key: str) -> tuple[bool, bool, bool]:
    a = next(a for a in d.alarms.alarms() if a.key == key)
    return a.active, a.acked, a.confirmed


def daemon(tmp: Path, drv: RecordingDriver, alarms: str = "") -> Daemon:
    path = write_plant(tmp, port=free_port(), watchdog="500ms", extra="")
    text = path.read_text(encoding="utf-8").replace("t1:\n", "t1:\n    description: Banco 1\n")
    path.write_text(text + alarms, encoding="utf-8")
    pdef = load_plant(str(path))
    d = Daemon(pdef, plant=Plant(pdef, drivers={"io": drv}), manage_gc=False)
    d.start()
    return d


def test_a_max_time_alarm_acknowledged_stays_active_until_its_cause_clears(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "runtime.controller.alarms")
    d = daemon(tmp_path, RecordingDriver("io", {"on_fault": "hold"}))
    key = "t1.gsJam.maxtime"
    try:
        assert [a.key for a in d.alarms.alarms()] == [
            "controller.fault", "controller.overruns", "driver.io", "t1.SFCError",
            "t1.gsJam.maxtime", "t2.SFCError", "t2.gsJam.maxtime"]
        assert state(d, key) == (False, True, True)
        d.call(lambda: d.plant.set("t1.sJam", True))
        wait_for(lambda: state(d, key)[0], "the max time alarm")
        assert state(d, key) == (True, False, False)
        with pytest.raises(AlarmRefused) as err:
            d.alarms.confirm(key, "operator")
        assert err.value.code == "BadInvalidState"
        assert d.alarms.acknowledge(key, "operator", "seen") == (
            f"alarm {key} acknowledged (active, acknowledged, unconfirmed)")
        with pytest.raises(AlarmRefused) as err:
            d.alarms.acknowledge(key, "operator")
        assert err.value.code == "BadConditionBranchAlreadyAcked"
        # a confirmation says the cause was dealt with: not while it is still there
        with pytest.raises(AlarmRefused) as err:
            d.alarms.confirm(key, "operator")
        assert (err.value.code, str(err.value)) == (
            "BadInvalidState", f"alarm {key} is still active: acknowledge the chart's "
            "SFCError first (the instance's Acknowledge, the console's 'ack'), then confirm "
            "it")
        time.sleep(0.3)
        assert state(d, key) == (True, True, False)  # acknowledged: still active
        lines = alarm_lines(d.status()["alarms"])
        assert lines == [f"alarm {key} (700) active, acknowledged, unconfirmed: t1 (Banco 1): "
                         "step gsJam over its max time 50ms"]
        # the cause clears: the chart's error acknowledged (and sJam off)
        d.call(lambda: d.plant.set("t1.sJam", False))
        d.call(lambda: d.plant.pulse("t1", "SFCQuitError"))
        wait_for(lambda: not state(d, key)[0], "the alarm inactive")
        assert alarm_lines(d.status()["alarms"]) == [
            f"alarm {key} (700) inactive, acknowledged, unconfirmed: t1 (Banco 1): "
            "step gsJam over its max time 50ms"]
        d.alarms.confirm(key, "operator", "fixed")
        assert alarm_lines(d.status()["alarms"]) == []  # no longer shown
        with pytest.raises(AlarmRefused) as err:
            d.alarms.acknowledge("t9.nothing", "operator")
        assert err.value.code == "BadNodeIdUnknown"
    finally:
        d.stop("end of test")
    said = [r.getMessage() for r in caplog.records if r.name == "runtime.controller.alarms"]
    assert said == [
        f"alarm {key} raised (severity 700): t1 (Banco 1): step gsJam over its max time 50ms",
        f"alarm {key} acknowledged by operator: seen (active, acknowledged, unconfirmed)",
        f"alarm {key} cleared (inactive, acknowledged, unconfirmed): t1 (Banco 1): step gsJam "
        "over its max time 50ms",
        f"alarm {key} confirmed by operator: fixed (inactive, acknowledged)"]


def test_driver_fault_controller_fault_and_overruns(tmp_path: Path) -> None:
    drv = RecordingDriver("io", {"on_fault": "hold"})
    d = daemon(tmp_path, drv, "alarms:\n  severity: {driver: 650}\n"
                              "  overruns: {count: 0, window: 2s}\n")
    try:
        drv.fail_with = DriverError("bus gone")
        wait_for(lambda: state(d, "driver.io")[0], "the driver alarm")
        a = next(a for a in d.alarms.alarms() if a.key == "driver.io")
        assert (a.severity, a.message) == (650, "driver io: bus gone")
        drv.fail_with = None
        wait_for(lambda: not state(d, "driver.io")[0], "the driver alarm cleared")
        # a scan longer than the cycle (not than the watchdog): an overrun
        drv.block_s = 0.05
        wait_for(lambda: state(d, "controller.overruns")[0], "the overruns alarm")
        wait_for(lambda: not state(d, "controller.overruns")[0], "overruns out of the window")
        d.call(lambda: d.plant.set("t1.sDiv", 0))  # 100 / 0 in a scan: a fault
        wait_for(lambda: state(d, "controller.fault")[0], "the fault alarm")
        msg = next(a.message for a in d.alarms.alarms() if a.key == "controller.fault")
        assert msg.startswith("controller fault: exception in scan: ZeroDivisionError")
        d.call(lambda: d.plant.set("t1.sDiv", 1))
        d.ack()
        wait_for(lambda: not state(d, "controller.fault")[0], "the fault alarm cleared")
        assert state(d, "controller.fault") == (False, False, False)  # still to acknowledge
    finally:
        d.stop("end of test")


def test_the_alarms_section_is_checked(tmp_path: Path) -> None:
    from runtime.errors import SourceError

    for section, words in (("alarms:\n  severity: {fault: 2000}\n", "expected 1 to 1000"),
                           ("alarms:\n  severity: {faults: 20}\n",
                            "unknown kind of alarm 'faults'"),
                           ("alarms:\n  overruns: {window: 0}\n", "expected 1s to 1h"),
                           ("alarms:\n  overrun: {}\n", "unknown key 'overrun' in alarms")):
        path = write_plant(tmp_path, port=free_port())
        path.write_text(path.read_text(encoding="utf-8") + section, encoding="utf-8")
        with pytest.raises(SourceError, match=words):
            load_plant(str(path))


def test_the_fault_alarm_names_the_fault_the_scan_saw(tmp_path: Path) -> None:
    """The board looks at the causes after the scan copied them: a fault acknowledged in
    between is still named by its reason (it said 'controller fault: None')."""
    d = daemon(tmp_path, RecordingDriver("io", {"on_fault": "hold"}))
    try:
        board = d.alarms
        board.close()  # its thread stopped: the causes evaluated here, by hand
        causes = board._causes  # noqa: SLF001 - the scan thread's copy, as on_scan takes it
        assert causes is not None and d.fault is None
        board.evaluate(causes.read("frozen for 158 ms", 0))
        assert [(a.active, a.message) for a in board.alarms()
                if a.key == "controller.fault"] == [
            (True, "controller fault: frozen for 158 ms")]
    finally:
        d.stop("end of test")


def test_an_online_change_of_the_alarms_section_is_said_and_applied(tmp_path: Path) -> None:
    """Merge of issue 29 with issue 25's diff: ``alarms:`` is a setting of the plant, so a
    reload that changes it says so and the board takes the new severities at the swap (the
    board kept the start's settings, and the diff did not name the section)."""
    d = daemon(tmp_path, RecordingDriver("io", {"on_fault": "hold"}),
               "alarms:\n  severity: {driver: 650}\n")
    try:
        path = Path(d.pdef.path)
        text = path.read_text(encoding="utf-8")
        path.write_text(text.replace("{driver: 650}", "{driver: 640}"), encoding="utf-8")
        result = d.reload()
        assert result.applied, result.refusals
        assert "plant: alarms changed" in result.lines
        wait_for(lambda: next(a.severity for a in d.alarms.alarms()
                              if a.key == "driver.io") == 640, "the new severity")
    finally:
        d.stop("end of test")


def test_the_journal_keeps_every_change_in_order_and_says_what_it_lost(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``AlarmBoard.changes``: each raise, acknowledge, clear and confirm once, in order,
    with its version, and the board read with them; a reader further behind than the
    ring (made 3 here) gets the newest it holds and is told the rest is lost."""
    monkeypatch.setattr(alarms_mod, "JOURNAL_MAX", 3)
    # a loaded test machine overruns now and then: that alarm kept quiet here
    d = daemon(tmp_path, RecordingDriver("io", {"on_fault": "hold"}),
               "alarms:\n  overruns: {count: 1000000}\n")
    key, board = "t1.SFCError", d.alarms
    try:
        start = board.version
        assert board.changes(start) == ([], start, None, False)
        for _round in range(2):
            d.call(lambda: d.plant.set("t1.SFCError", True))
            wait_for(lambda: state(d, key)[0], "the alarm raised")
            board.acknowledge(key, "operator", "seen")
            d.call(lambda: d.plant.pulse("t1", "SFCQuitError"))
            wait_for(lambda: not state(d, key)[0], "the alarm cleared")
            board.confirm(key, "operator", "done")
        changes, version, alarms, lost = board.changes(start)
        assert version == start + 8 and lost
        assert [(v, a["key"], a["active"], a["acked"], a["confirmed"]) for v, a in changes] == [
            (start + 6, key, True, True, False), (start + 7, key, False, True, False),
            (start + 8, key, False, True, True)]
        assert alarms == board.as_list()
        # a reader the ring still holds: only what it has not seen, nothing lost
        changes, version, _alarms, lost = board.changes(start + 6)
        assert [v for v, _a in changes] == [start + 7, start + 8] and not lost
    finally:
        d.stop("end of test")
