"""``reload`` on the console, over the rig's real pty (serial line) and Unix socket: it
needs the PIN like ``set``, except from the controller's own user on the Unix socket
(systemd's ExecReload); the reply lists what changed or, refused, each reason on its own
line; a running trace ends with one line ``reloaded``; ``status`` shows the last reload;
``reload --back`` returns to the program before (docs/online-change.md)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

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


def _swap_queued_then(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, line: bytes,
                      first: bytes | None = None) -> tuple[list[str], Any, Any, Any]:
    """A console command typed while a reload's swap waits for the scan: (its reply,
    daemon, service, session). The swap waits for the next cycle's idle time, as in any
    cycle of 20 ms or less; a 300 ms cycle makes that window wide (a longer cycle would
    serve the swap at once, when it is queued: not waking the scan thread keeps it
    waiting)."""
    import threading
    import time

    from runtime.console.service import ConsoleService
    from runtime.controller.daemon import Daemon
    from runtime.engine.plant import Plant
    from runtime.language.plantfile import load_plant
    from tests.daemon.daemonkit import RecordingDriver, plant_yaml, wait_until
    from tests.daemon.test_reload import CYCLER

    (tmp_path / "runner.yaml").write_text(CYCLER, encoding="utf-8")
    (tmp_path / "plant.yaml").write_text(plant_yaml(cycle="300ms", watchdog="1s"),
                                         encoding="utf-8")
    pdef = load_plant(str(tmp_path / "plant.yaml"))
    d = Daemon(pdef, plant=Plant(pdef, drivers={"io": RecordingDriver("io")}),
               manage_gc=False)
    d.start()
    svc = ConsoleService(d, pin_hash=None)
    s = svc.session("tcp:127.0.0.1:5000", trusted=True)
    if first is not None:
        assert s.handle(first)[-1] == "ok"
    monkeypatch.setattr(d.scheduler, "wake", lambda: None)  # served at the next idle time
    (tmp_path / "runner.yaml").write_text(CYCLER.replace("gsA.T >= 30ms", "gsA.T >= 40ms"),
                                          encoding="utf-8")
    done: list[Any] = []
    t = threading.Thread(target=lambda: done.append(d.reload()))
    t.start()
    end = time.monotonic() + 30.0
    while not d._calls and not done:  # the swap queued for the scan's idle time
        assert time.monotonic() < end, "the swap was never queued"
        time.sleep(0.0005)
    reply = s.handle(line)
    t.join()
    assert done and done[0].applied, done
    wait_until(lambda: d.plant is not None, 1.0, "the plant")
    return reply, d, svc, s


def test_a_command_racing_a_reload_is_refused_not_applied_to_the_old_plant(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """An 'unforce' that reached the scan after the swap acted on the replaced plant: the
    console said 'released' while the running plant kept the output forced, owned by
    nobody (a review of the online change found it). Now it is refused, nothing done."""
    reply, d, svc, s = _swap_queued_then(tmp_path, monkeypatch, b"unforce io.Q1",
                                         first=b"force io.Q1 1")
    try:
        # the swap was queued first: the command reaches the scan after it
        assert "reloaded meanwhile" in reply[-1], reply
        assert d.plant.is_forced("io.Q1") and "force io.Q1" in svc.holdings()
        assert s.handle(b"unforce io.Q1")[-1] == "ok"  # again: on the running plant
        assert not d.plant.is_forced("io.Q1") and "force io.Q1" not in svc.holdings()
    finally:
        s.close("end of test")
        d.stop("end of test")


def test_iocheck_racing_a_reload_never_leaves_the_charts_running_unsaid(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reply, d, svc, s = _swap_queued_then(tmp_path, monkeypatch, b"iocheck on")
    try:
        assert "reloaded meanwhile" in reply[-1], reply
        assert not d.plant.iocheck and "iocheck" not in svc.holdings()
    finally:
        s.close("end of test")
        d.stop("end of test")


def test_a_new_pin_takes_effect_at_the_reload_and_locks_the_old_sessions(
        tmp_path: Path) -> None:
    """Rotating a leaked PIN by editing the plant file and reloading: the new PIN unlocks,
    the old one no longer does, and a session unlocked with the old one is locked again
    (before, the reload said 'console PIN changed' and the old PIN went on working)."""
    from runtime.console.service import ConsoleService
    from runtime.controller.daemon import Daemon
    from runtime.engine.plant import Plant
    from runtime.language.plantfile import load_plant
    from tests.daemon.daemonkit import RecordingDriver, plant_yaml
    from tests.daemon.test_reload import CYCLER

    old, new = hash_pin("1111", n=16, r=1, p=1), hash_pin("2222", n=16, r=1, p=1)
    (tmp_path / "runner.yaml").write_text(CYCLER, encoding="utf-8")
    plant = tmp_path / "plant.yaml"
    plant.write_text(plant_yaml(extra=f"monitor:\n  pin_hash: '{old}'\n"), encoding="utf-8")
    pdef = load_plant(str(plant))
    d = Daemon(pdef, plant=Plant(pdef, drivers={"io": RecordingDriver("io")}),
               manage_gc=False)
    d.start()
    svc = ConsoleService(d, pin_hash=pdef.pin_hash)
    before, other = svc.session("tcp:a"), svc.session("tcp:b", peer="tcp:b")
    try:
        assert before.handle(b"unlock 1111")[-1] == "ok"
        plant.write_text(plant_yaml(extra=f"monitor:\n  pin_hash: '{new}'\n"),
                         encoding="utf-8")
        assert before.handle(b"reload")[-1] == "ok"
        assert before.handle(b"set m.sMaint 1")[-1] == "error locked: 'unlock PIN' first"
        assert other.handle(b"unlock 1111")[-1].startswith("error wrong PIN")
        assert other.handle(b"unlock 2222")[-1] == "ok"
        assert other.handle(b"set m.sMaint 1")[-1] == "ok"
    finally:
        before.close("end of test")
        other.close("end of test")
        d.stop("end of test")


def test_diff_refuses_what_reload_refuses(tmp_path: Path,
                                          capsys: Any) -> None:
    """`softplc diff` and `reload` say the same of a plant setting the running controller
    set up at its start (before, diff said 'can be applied online' and reload refused)."""
    from runtime.cli import main
    from tests.daemon.daemonkit import plant_yaml
    from tests.daemon.test_reload import CYCLER

    (tmp_path / "runner.yaml").write_text(CYCLER, encoding="utf-8")
    (tmp_path / "a.yaml").write_text(plant_yaml(), encoding="utf-8")
    (tmp_path / "b.yaml").write_text(plant_yaml(watchdog="200ms"), encoding="utf-8")
    assert main(["diff", str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml")]) == 1
    out = capsys.readouterr().out
    assert "cannot be applied online" in out
    assert "plc: watchdog changed: it takes effect only at a restart" in out
