"""What the controller logs of its charts: step changes when the plant asks for them
(``log: steps``, per instance or plant-wide), SFCError set and cleared, and overruns as one
line per burst. Through a real daemon on simulated I/O, waiting on the log lines."""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from runtime.controller.events import EventWatcher
from runtime.controller.stats import ScanStats
from runtime.engine.plant import Plant
from runtime.errors import SourceError
from runtime.language.plantfile import load_plant
from tests.daemon.daemonkit import CHART, MakeDaemon, plant_yaml, wait_until

LOGGER = "runtime.controller.events"


def lines(caplog: pytest.LogCaptureFixture, part: str = "") -> list[str]:
    """The events' log lines (containing ``part``), as the handler would print them."""
    return [r.getMessage() for r in list(caplog.records)
            if r.name == LOGGER and part in r.getMessage()]


def said(caplog: pytest.LogCaptureFixture, part: str) -> bool:
    return bool(lines(caplog, part))


@pytest.fixture(autouse=True)
def _info(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)


def test_log_steps_on_an_instance_logs_every_step_change(
        make_daemon: MakeDaemon, caplog: pytest.LogCaptureFixture) -> None:
    d, drv = make_daemon(extra="    log: steps\n")
    wait_until(lambda: d.scan_stats.count > 2, what="scans")
    drv.inputs["I0"] = 1
    wait_until(lambda: said(caplog, "gsRun activated"), what="the activation line")
    drv.inputs["I0"] = 0
    wait_until(lambda: said(caplog, "gsRun deactivated"), what="the deactivation line")
    got = lines(caplog, "step")
    assert [x.split(" at scan ")[0] for x in got] == [
        "m: step gsIdle deactivated", "m: step gsRun activated",
        "m: step gsRun deactivated", "m: step gsIdle activated"], got
    scans = [int(x.rsplit(" ", 1)[1]) for x in got]
    assert scans[0] == scans[1] and scans[2] == scans[3] and scans[1] < scans[2], got


def test_steps_are_not_logged_unless_asked(make_daemon: MakeDaemon,
                                           caplog: pytest.LogCaptureFixture) -> None:
    d, drv = make_daemon()
    drv.inputs["I0"] = 1
    wait_until(lambda: d.plant.get("m.gsRun.X"), what="gsRun")
    drv.inputs["I0"] = 0
    wait_until(lambda: d.plant.get("m.gsIdle.X"), what="gsIdle")
    n = d.scan_stats.count
    wait_until(lambda: d.scan_stats.count > n + 2, what="scans")
    assert lines(caplog, "step") == []


def test_log_steps_plant_wide_and_off_for_one_instance(tmp_path: Path) -> None:
    (tmp_path / "runner.yaml").write_text(CHART, encoding="utf-8")
    text = plant_yaml().replace("plc:\n", "plc:\n  log: steps\n")
    text += ("  quiet:\n    grafcet: runner.yaml\n    log: none\n"
             "    inputs: {iGo: io.I1}\n    outputs: {oRun: io.Q2, oLamp: io.Q3}\n")
    (tmp_path / "plant.yaml").write_text(text, encoding="utf-8")
    pdef = load_plant(str(tmp_path / "plant.yaml"))
    assert pdef.instances["m"].log_steps and not pdef.instances["quiet"].log_steps


def test_a_bad_log_value_is_refused_with_its_line(tmp_path: Path) -> None:
    (tmp_path / "runner.yaml").write_text(CHART, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(plant_yaml(extra="    log: everything\n"),
                                         encoding="utf-8")
    with pytest.raises(SourceError) as e:
        load_plant(str(tmp_path / "plant.yaml"))
    assert e.value.loc.line == 12
    assert "log: expected steps or none, found 'everything'" in str(e.value)


def test_sfc_error_set_and_cleared_are_logged(make_daemon: MakeDaemon,
                                              caplog: pytest.LogCaptureFixture) -> None:
    d, drv = make_daemon()
    drv.inputs["I0"] = 1  # gsRun has max: 200ms
    wait_until(lambda: said(caplog, "SFCError"), what="the SFCError line")
    got = lines(caplog, "SFCError")
    assert len(got) == 1 and got[0].startswith(
        "m: SFCError: step gsRun active longer than its max 200ms, at scan "), got
    assert d.ack() == "SFCError of m (set by step gsRun) acknowledged"
    wait_until(lambda: len(lines(caplog, "SFCError")) == 2, what="the cleared line")
    assert lines(caplog, "SFCError")[1].startswith(
        "m: SFCError cleared (was set by step gsRun), at scan "), lines(caplog)


def test_an_overrun_burst_is_one_line_with_its_count(make_daemon: MakeDaemon,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    d, drv = make_daemon(cycle="10ms", watchdog="500ms")
    wait_until(lambda: d.scan_stats.count > 2, what="scans")
    for i in range(1, 4):  # three slow reads in a row: 40 ms scans of a 10 ms cycle
        drv.block_s = 0.04
        wait_until(lambda: d.scan_stats.overruns >= i, what="an overrun")  # noqa: B023

    def ours() -> list[str]:  # the burst of the slow reads (a loaded machine adds others)
        return [x for x in lines(caplog, "overran")
                if float(x.split("the longest took ")[1].split(" ms")[0]) >= 40.0]
    wait_until(lambda: bool(ours()), timeout=10.0, what="the overrun line")
    got = ours()
    assert len(got) == 1, lines(caplog, "overran")
    count = int(got[0].split(" ")[0])
    assert count >= 3 and " overran the 10 ms cycle between scans " in got[0], got
    assert d.fault is None


# -- the watcher on a virtual clock ------------------------------------------------------
def _watcher(tmp_path: Path, now: list[int]) -> tuple[EventWatcher, ScanStats]:
    (tmp_path / "runner.yaml").write_text(CHART, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(plant_yaml(), encoding="utf-8")
    pdef = load_plant(str(tmp_path / "plant.yaml"))
    stats = ScanStats()
    return EventWatcher(Plant(pdef, sim=True), stats, clock=lambda: now[0]), stats


def test_overruns_close_a_burst_after_a_quiet_second(tmp_path: Path,
                                                     caplog: pytest.LogCaptureFixture) -> None:
    now = [0]
    w, stats = _watcher(tmp_path, now)
    try:
        for n in range(1, 400):  # 10 ms cycles; overruns at scans 10, 11 and 300
            now[0] = n * 10_000_000
            stats.record(12_000_000 if n in (10, 11, 300) else 1_000_000, 0)
            if n in (10, 11, 300):
                stats.overruns += 1
            w(n)
        w.close()
    finally:
        w.close()
    got = lines(caplog, "overran")
    assert got == [
        "2 cycles overran the 10 ms cycle between scans 10 and 11 (in 0.010 s; the "
        "longest took 12.0 ms; 0 deadlines skipped)",
        "1 cycle overran the 10 ms cycle at scan 300 (the longest took 12.0 ms; 0 "
        "deadlines skipped)"], got


def test_a_continuing_burst_is_reported_every_ten_seconds(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    now = [0]
    w, stats = _watcher(tmp_path, now)
    try:
        for n in range(1, 2501):  # every cycle overruns for 25 s (10 ms each)
            now[0] = n * 10_000_000
            stats.record(11_000_000, 0)
            stats.overruns += 1
            w(n)
    finally:
        w.close()
    got = lines(caplog, "overran")
    assert [x.split(" cycles")[0] for x in got] == ["1000", "1000", "500"], got


TICK = """\
grafcet: Tick
outputs: [oLamp]
steps:
  s0: {initial: true}
  s1: {actions: [oLamp]}
transitions:
  - {from: s0, to: s1, when: "s0.T >= 100ms"}
  - {from: s1, to: s0, when: "s1.T >= 100ms"}
"""


def test_softplc_run_writes_the_step_lines_to_its_log(tmp_path: Path) -> None:
    (tmp_path / "tick.yaml").write_text(TICK, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(
        "plc: {cycle: 10ms, watchdog: 500ms, log: steps}\ndrivers:\n  io: {type: sim}\n"
        "instances:\n  t:\n    grafcet: tick.yaml\n    outputs: {oLamp: io.Q0}\n",
        encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "runtime.cli", "run", "--sim",
                           str(tmp_path / "plant.yaml"), "--for", "1s"],
                          capture_output=True, text=True, timeout=60,
                          env={**os.environ, "JOURNAL_STREAM": ""})
    assert proc.returncode == 0, proc.stderr
    assert re.search(r" INFO runtime\.controller\.events: t: step s1 activated at scan \d+$",
                     proc.stderr, re.M), proc.stderr


def test_an_sfc_error_set_by_hand_names_no_step(make_daemon: MakeDaemon,
                                                caplog: pytest.LogCaptureFixture) -> None:
    """SFCError written (console ``set``, the chart itself): no step was over its max, and
    the lines say it was set by the chart (they said 'step  active longer than its max ?',
    then '(was step )' when cleared)."""
    d, drv = make_daemon()
    d.call(lambda: d.plant.set("m.SFCError", True))
    wait_until(lambda: said(caplog, "SFCError"), what="the SFCError line")
    got = lines(caplog, "SFCError")
    assert len(got) == 1 and got[0].startswith("m: SFCError set by the chart, at scan "), got
    assert d.ack() == "SFCError of m (set by the chart) acknowledged"
    wait_until(lambda: len(lines(caplog, "SFCError")) == 2, what="the cleared line")
    # it said 'SFCError cleared (was step ), ...'
    assert lines(caplog, "SFCError")[1].startswith(
        "m: SFCError cleared (was set by the chart), at scan "), lines(caplog)
