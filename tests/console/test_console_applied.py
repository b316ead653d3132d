"""After the safe reaction, the console and the monitor show the outputs the machine has.

Issue: a page holding a force was closed; the controller halted and the output's point
went to 0, but ``get tank.oMixer`` and the monitor (``oMixer=1``) still showed 1, the
stopped chart's value. A chart output reads as applied (its point, through the binding:
runtime/engine/names.py); where the chart's own value differs, ``get`` and ``status`` say
it is not applied, with what the point holds. Over a real Unix socket console of a
running controller, halted the way the issue's was: a session holding a force ends."""

from __future__ import annotations

from pathlib import Path

from runtime.console.client import ConsoleClient
from runtime.console.links import Target
from runtime.console.view import View
from tests.console.consolekit import socket_client, wait_for
from tests.console.test_console_iolist import console

TANK = """\
grafcet: Tank
inputs: [iGo]
outputs: [oMixer, oValve, {oSpeed: int}]
steps:
  gsMix: {initial: true, actions: [oMixer, oValve]}
  gsDone: {}
transitions:
  - {from: gsMix, to: gsDone, when: iGo}
post:
  - oSpeed := 1400
"""


def plant(tmp: Path) -> Path:
    (tmp / "tank.yaml").write_text(TANK, encoding="utf-8")
    path = tmp / "plant.yaml"
    path.write_text(
        "drivers:\n  sim: {type: sim}\ninstances:\n  tank:\n    grafcet: tank.yaml\n"
        "    inputs: {iGo: sim.I0}\n"
        "    outputs: {oMixer: sim.Q2, oValve: {from: sim.Q3, invert: true},"
        " oSpeed: sim.HR0}\n", encoding="utf-8")
    return path


def monitor_lines(sock: str) -> list[str]:
    client = ConsoleClient(Target.parse(sock).open())
    client.start()
    view = View(sock)
    view.refresh(client)
    client.close()
    return view.lines(200)


def test_after_the_safe_reaction_get_status_and_the_monitor_show_the_outputs_off(
        tmp_path: Path) -> None:
    with console(plant(tmp_path), tmp_path) as (daemon, sock):
        s = socket_client(sock)
        wait_for(lambda: daemon.call(lambda: daemon.plant.get("sim.Q2")) == 1,
                 "the mixer on")
        # running: the outputs as the chart says, nothing "not applied"
        assert s.ok("get tank.oMixer tank.oSpeed") == [
            "tank.oMixer=1  -> sim.Q2", "tank.oSpeed=1400  -> sim.HR0"]
        assert not any("not applied" in x for x in s.ok("status"))
        assert "oMixer=1" in " ".join(monitor_lines(sock))
        # the page's session held a force, and was closed: halted, every output off
        held = socket_client(sock)
        held.ok("force tank.oMixer 1")
        held.close()
        wait_for(lambda: daemon.status()["state"] == "halted", "the halt")
        assert daemon.call(lambda: daemon.plant.get("sim.Q2")) == 0
        assert daemon.call(lambda: daemon.plant.get("tank.oMixer")) is True  # the chart's
        assert s.ok("get tank.oMixer") == [
            "tank.oMixer=0 (not applied: the chart's value is 1)"]
        assert s.ok("get tank.oMixer tank.oValve tank.oSpeed") == [
            "tank.oMixer=0 (not applied: the chart's value is 1)  -> sim.Q2",
            # inverted: its point off is the chart's 1 (de-energised), as the chart says
            "tank.oValve=1  -> sim.Q3 inverted",
            "tank.oSpeed=0 (not applied: the chart's value is 1400)  -> sim.HR0"]
        status = s.ok("status")
        assert "not applied: tank.oMixer: the chart's 1, sim.Q2 holds 0" in status, status
        assert "not applied: tank.oSpeed: the chart's 1400, sim.HR0 holds 0" in status
        s.cmd("json on")
        got = s.jcmd("get tank.oMixer")
        assert got["values"] == {"tank.oMixer": 0}
        assert got["not_applied"] == {"tank.oMixer": 1}
        assert s.jcmd("status")["not_applied"]["tank.oMixer"] == {
            "chart": 1, "applied": 0, "point": "sim.Q2", "holds": 0}
        s.close()
        lines = monitor_lines(sock)
        row = next(x for x in lines if x.startswith("  out "))
        assert "oMixer=0" in row and "oSpeed=0" in row, lines
        assert "not applied  tank.oMixer: the chart's 1, sim.Q2 holds 0" in lines, lines
