"""How the console shows an instance a forced ``reload`` left without an active step: the
reload's reply says it is in fault, ``status`` names it on an ``inhibit:`` line (and in
JSON ``instance_faults``) while the other instance runs on, its outputs stay off, and
``ack`` restarts it from its initial situation (docs/online-change.md)."""

from __future__ import annotations

import time
from collections.abc import Callable

from tests.console.consolekit import Rig
from tests.console.test_console_reload import chart_copy

WHY = "no active step left (the forced change dropped gsParado)"


def test_a_forced_reload_that_leaves_t1_stepless_is_shown_as_t1_in_fault(
        rigs: Callable[..., Rig]) -> None:
    rig = rigs()
    chart = chart_copy(rig)
    rig.set_input("I4", 1)  # t2's stop released (NC), then MARCHA: t2 opens its drawer
    rig.set_input("I5", 1)
    deadline = time.monotonic() + 5.0
    while rig.steps("t2") != ["gsAbrir"] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert rig.steps("t2") == ["gsAbrir"] and rig.steps("t1") == ["gsParado"]
    # gsParado renamed without renamed_from: removed, active in t1 only
    chart.write_text(chart.read_text(encoding="utf-8").replace("gsParado", "gsStop"),
                     encoding="utf-8")
    sock = rig.connect()
    out = sock.ok("reload --force")
    assert out[0].startswith("reload applied in "), out
    assert (f"  t1: in fault, its outputs off: {WHY}; ack, or reload --restart t1, starts "
            "it again from its initial situation") in out, out
    status = sock.ok("status")
    assert status[0] == "state running", status
    assert (f"inhibit: t1: in fault: {WHY} (its outputs off until ack or reload --restart "
            "t1)") in status, status
    assert "t1: (no active step)" in status and "t2: gsAbrir" in status, status
    assert rig.read("rio.Q2") == 0 and rig.read("t1.oParado") is False  # off, not scanned
    js = rig.connect()
    js.jcmd("json on")
    data = js.jcmd("status")
    assert data["instance_faults"] == {"t1": WHY}, data
    assert sock.ok("ack") == [f"t1: in fault ({WHY}): restarted from its initial situation"]
    assert rig.steps("t1") == ["gsStop"] and rig.steps("t2") in (["gsAbrir"], ["gsCerrar"])
    assert not [x for x in sock.ok("status") if x.startswith("inhibit: t1")]
