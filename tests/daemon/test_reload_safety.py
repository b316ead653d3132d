"""An online change is never less safe than a cold start (issue 31), in a running Daemon on
a recording driver: an output whose last action the change removes goes off in the swap
scan; an instance a forced change leaves without an active step is in fault (not scanned,
its outputs off, said by ``status``) until ``ack`` or ``reload --restart``; a reload whose
child process fails is refused, never loaded in the controller's process."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from runtime.controller.daemon import Daemon
from runtime.engine.plant import Plant
from tests.daemon.daemonkit import MakeDaemon, RecordingDriver, wait_until
from tests.daemon.test_reload import CYCLER, edit, no_stop_since, running, steps


def swap_index(daemon: Daemon, drv: RecordingDriver) -> list[int]:
    """Filled at the swap (in the scan thread, between two cycles) with the number of
    images the driver had been sent: every later one is the new program's."""
    at: list[int] = []

    def hook(plant: Plant) -> Callable[[], None]:
        return lambda: at.append(len(drv.sent))
    daemon.on_reload(hook)
    return at


def sent_since(drv: RecordingDriver, index: int, n: int = 5) -> list[dict[str, int]]:
    """The output images sent from ``index`` on, once there are ``n`` of them."""
    wait_until(lambda: len(drv.sent) >= index + n, 5.0, "cycles after the swap")
    with drv.lock:
        return [image for _, image in drv.sent[index:]]


def test_an_output_whose_last_action_is_removed_goes_off_in_the_swap_scan(
        make_daemon: MakeDaemon, tmp_path: Path) -> None:
    """oRun is driven by gsA and gsB, one of them active; the edit removes it from both:
    a cold start of the edited chart never sets it, so neither does the carried one."""
    daemon, drv, chart = running(make_daemon, tmp_path)
    at = swap_index(daemon, drv)
    edit(chart, "gsA: {actions: [oRun]}", "gsA: {}")
    edit(chart, "gsB: {actions: [oRun, ", "gsB: {actions: [")
    result = daemon.reload()
    assert result.applied, result.refusals
    assert ("m: output oRun no longer driven by the chart: False from the swap on, as after "
            "a cold start") in result.lines, result.lines
    images = sent_since(drv, at[0])
    assert all(image["Q0"] == 0 for image in images), images  # the first one too
    assert steps(daemon) in (["gsA"], ["gsB"])  # the chart itself goes on


def test_a_forced_change_that_drops_the_only_active_step_faults_that_instance(
        make_daemon: MakeDaemon, tmp_path: Path) -> None:
    """gsA and gsB become gsC: forced, the active one is dropped and the instance has no
    active step. It is in fault, not running dead: not scanned, every output of it off
    (oLamp := 1 in post would hold Q1 on), said by status; ``reload --restart m`` and
    ``ack`` each start it again from its initial situation."""
    daemon, drv, chart = running(make_daemon, tmp_path)
    at = swap_index(daemon, drv)
    gsc = (CYCLER.replace("  gsA: {actions: [oRun]}\n", "")
           .replace("  gsB: {actions: [oRun, \"P1 sN := sN + 1\"]}\n",
                    "  gsC: {actions: [oRun]}\n")
           .replace('  - {from: gsIdle, to: gsA, when: iGo}\n'
                    '  - {from: gsA, to: gsB, when: "gsA.T >= 30ms"}\n'
                    '  - {from: gsB, to: gsA, when: "gsB.T >= 30ms"}\n',
                    '  - {from: gsIdle, to: gsC, when: iGo}\n'
                    '  - {from: gsC, to: gsIdle, when: "iGo\'"}\n')
           .replace("oLamp := gsA.X", "oLamp := 1"))
    chart.write_text(gsc, encoding="utf-8")
    refused = daemon.reload()
    assert not refused.applied and any("removed while it is active" in r
                                       for r in refused.refusals), refused.refusals
    result = daemon.reload(force=True)
    assert result.applied, result.refusals
    assert steps(daemon) == []
    assert list(result.instance_faults) == ["m"], result.lines
    assert any(line.startswith("m: in fault, its outputs off: no active step left (the "
                               "forced change dropped gs") for line in result.lines), result.lines
    images = sent_since(drv, at[0])
    assert all(image == {"Q0": 0, "Q1": 0} for image in images), images
    status = daemon.status()
    assert status["state"] == "running" and list(status["instance_faults"]) == ["m"]
    assert any(x.startswith("m: in fault: no active step left") and "ack or reload "
               "--restart m" in x for x in status["inhibits"]), status["inhibits"]
    # reload --restart m (the same files): m starts again from gsIdle, iGo on: gsC
    assert daemon.reload(restart=["m"]).applied
    wait_until(lambda: steps(daemon) == ["gsC"], 5.0, "m restarted into gsC")
    assert daemon.status()["instance_faults"] == {}
    before = len(drv.sent)
    wait_until(lambda: len(drv.sent) > before + 2 and drv.sent[-1][1] == {"Q0": 1, "Q1": 1},
               5.0, "m's outputs on again")
    # in fault again (gsC dropped for gsD), then ack starts it again
    edit(chart, "gsC", "gsD")
    assert list(daemon.reload(force=True).instance_faults) == ["m"]
    assert daemon.ack() == ("m: in fault (no active step left (the forced change dropped "
                            "gsC)): restarted from its initial situation")
    wait_until(lambda: steps(daemon) == ["gsD"], 5.0, "m acknowledged into gsD")
    assert daemon.status()["instance_faults"] == {}


def test_a_reload_whose_child_fails_is_refused_and_changes_nothing(
        make_daemon: MakeDaemon, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    daemon, drv, chart = running(make_daemon, tmp_path)
    before, plant0 = len(drv.sent), daemon.plant
    edit(chart, "gsA.T >= 30ms", "gsA.T >= 40ms")
    monkeypatch.setattr(sys, "executable", "/bin/false")
    result = daemon.reload()
    assert not result.applied
    assert result.refusals == ["the reload's child process failed (exit 1)"]
    assert daemon.plant is plant0
    sent_since(drv, before, 3)
    no_stop_since(drv, before)
