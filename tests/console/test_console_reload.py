"""``reload`` on the console, over the rig's real pty (serial line) and Unix socket: it
needs the PIN like ``set``, except from the controller's own user on the Unix socket
(systemd's ExecReload); the reply lists what changed or, refused, each reason on its own
line; a running trace ends with one line ``reloaded``; ``status`` shows the last reload;
``reload --back`` returns to the program before (docs/online-change.md)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from runtime.controller.pin import hash_pin
from tests.console.consolekit import CHART, Rig

PIN = "4711"
HASH = hash_pin(PIN, iterations=1000)


def chart_copy(rig: Rig) -> Path:
    """The rig's plant file made to run a copy of the drawer chart that the test edits
    (the running program is still the original's until a reload)."""
    chart = Path(rig.tmp) / "drawer.yaml"
    chart.write_text(Path(CHART).read_text(encoding="utf-8"), encoding="utf-8")
    plant = Path(rig.tmp) / "plant.yaml"
    plant.write_text(plant.read_text(encoding="utf-8").replace(str(CHART), str(chart)),
                     encoding="utf-8")
    return chart


def test_reload_over_the_pty_and_the_socket(rigs: Callable[..., Rig]) -> None:
    rig = rigs(trusted=False, pin_hash=HASH)
    chart = chart_copy(rig)
    text = chart.read_text(encoding="utf-8")
    chart.write_text(text.replace("gsAbrir.T >= 10s", "gsAbrir.T >= 12s"), encoding="utf-8")
    plant0 = rig.plant
    ser = rig.serial()
    assert ser.error("reload") == "locked: 'unlock PIN' first"  # like set: the PIN
    assert rig.plant is plant0
    watcher = rig.connect()
    watcher.ok("trace on")
    sock = rig.connect()  # this process's uid: the controller's own user
    assert sock.error("reload --now") == ("usage: reload [--force] [--restart INSTANCE]... "
                                          "[--back]; not '--now'")
    out = sock.ok("reload")
    assert out[0].startswith("reload applied in ") and "change(s)" in out[0], out
    assert [line[:6] for line in out[1:]] == ["  t1: ", "  t2: "], out  # runtime.change's
    assert all("10s" in line and "12s" in line for line in out[1:]), out  # lines
    assert rig.plant is not plant0
    watcher.until(lambda line: line == "reloaded")  # the trace ends with one line
    watcher.ok("get t1.gsParado.X")  # the session goes on, on the new plant's names
    status = sock.ok("status")
    assert any(line.startswith("last reload at ") and "change" in line for line in status), \
        status
    # refused: the active initial step renamed without renamed_from: is removed
    chart.write_text(text.replace("gsParado", "gsStop"), encoding="utf-8")
    plant1 = rig.plant
    out = sock.cmd("reload")
    assert out[-1] == "error reload refused (2 reasons): nothing changed", out
    for inst in ("t1", "t2"):
        assert (f"refused: {inst}: step gsParado removed while it is active (--restart "
                f"{inst} restarts that instance)") in out, out
    assert sock.cmd("json on")
    reply = json.loads(sock.cmd("reload")[-1])
    assert reply["ok"] is False and len(reply["refusals"]) == 2 and not reply["applied"]
    assert rig.plant is plant1
    # the operator at the serial line, with the PIN: back to the program before
    ser.ok(f"unlock {PIN}")
    out = ser.ok("reload --back")
    assert out[0].startswith("reload --back applied in "), out
    assert rig.daemon.pdef.instances["t1"].grafcet.path == str(CHART)
    assert rig.steps("t1") == ["gsParado"] and rig.state() == "running"
