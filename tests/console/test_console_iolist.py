"""The I/O list at the console (issue 29): ``get`` shows each name's unit and description,
``why`` each active step's description, ``status`` (JSON) what the instances and their
active steps are, and the monitor shows them; over a real Unix socket console of a
running controller."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from runtime.console.client import ConsoleClient
from runtime.console.links import Target
from runtime.console.server import ConsoleServer
from runtime.console.service import ConsoleService
from runtime.console.view import View
from runtime.controller.daemon import Daemon
from runtime.language.model import ConsoleEntry
from runtime.language.plantfile import load_plant
from tests.console.consolekit import LineClient, socket_client

ROOT = Path(__file__).resolve().parents[2]
DRAWER = ROOT / "configs" / "drawer_tester" / "plant_sim.yaml"

TANK = """\
grafcet: Tank
inputs:
  - {iNivel: {type: real, description: level in the tank}}
outputs: [oBomba]
memory:
  sConsigna: {init: 50.5, description: level set point}
steps:
  gsLlenar: {initial: true, description: filling the tank}
  gsLleno: {}
transitions:
  - {from: gsLlenar, to: gsLleno, when: "iNivel >= sConsigna"}
post:
  - oBomba := gsLlenar.X
"""


@contextmanager
def console(path: Path, tmp: Path) -> Iterator[tuple[Daemon, str]]:
    """The plant of ``path`` running on sim I/O with a trusted socket console in ``tmp``
    (the shipped plant's own console and retained data moved there)."""
    pdef = load_plant(str(path))
    sock = str(tmp / "c.sock")
    pdef.consoles = [ConsoleEntry("socket", sock, trusted=True)]
    pdef.retain_path = str(tmp / "retain.json") if pdef.retain_path else None
    daemon = Daemon(pdef, sim=True, manage_gc=False)
    daemon.start()
    server = ConsoleServer(ConsoleService(daemon, pdef.pin_hash), pdef.consoles)
    server.start()
    try:
        yield daemon, sock
    finally:
        server.stop()
        daemon.stop("end of test")


def test_get_and_why_say_what_the_drawer_testers_signals_are(tmp_path: Path) -> None:
    with console(DRAWER, tmp_path) as (daemon, sock):
        s: LineClient = socket_client(sock)
        got = s.ok("get tester1.iParo tester1.oAbrir sim.I1")
        assert got == [
            'tester1.iParo=1  <- sim.I0 inverted  "Pulsador de paro SJP (NC)"',
            'tester1.oAbrir=0  -> sim.Q0  "Contactor QAA, abrir el cajón"',
            'sim.I1=0  tester1.iMarcha=0  "Pulsador de marcha SJM"']
        assert s.ok("why tester1")[0].startswith("gsParado active for ")
        assert s.ok("why tester1")[0].endswith(
            '"Test stopped (power-up, stop at end of cycle, end of test, acknowledged '
            'failure)"')
        s.cmd("json on")
        data = s.jcmd("get tester1.iParo tester1.gsParado.T")
        assert data["meanings"] == {
            "tester1.iParo": {"description": "Pulsador de paro SJP (NC)"},
            "tester1.gsParado.T": {"description": "Test stopped (power-up, stop at end of "
                                                  "cycle, end of test, acknowledged failure)",
                                   "unit": "C26", "symbol": "ms"}}
        status = s.jcmd("status")
        assert status["descriptions"]["tester1"] == "Banco de ensayo de guías de cajón 1"
        s.close()


def test_units_at_the_console_and_in_the_monitor(tmp_path: Path) -> None:
    (tmp_path / "tank.yaml").write_text(TANK, encoding="utf-8")
    path = tmp_path / "plant.yaml"
    path.write_text(
        "drivers:\n  io: {type: sim}\ninstances:\n  t1:\n    grafcet: tank.yaml\n"
        "    description: Depósito 1\n"
        "    inputs: {iNivel: {from: io.level, unit: cm, range: [0, 150]}}\n"
        "    outputs: {oBomba: {from: io.Q0, description: bomba P1}}\n", encoding="utf-8")
    with console(path, tmp_path) as (daemon, sock):
        s = socket_client(sock)
        assert s.ok("get t1.iNivel t1.sConsigna") == [
            't1.iNivel=0 cm  <- io.level  "level in the tank"',
            't1.sConsigna=50.5  "level set point"']
        s.cmd("json on")
        assert s.jcmd("get t1.iNivel")["meanings"] == {"t1.iNivel": {
            "description": "level in the tank", "unit": "CMT", "symbol": "cm",
            "range": [0.0, 150.0]}}
        s.close()
        client = ConsoleClient(Target.parse(sock).open())
        client.start()
        view = View(sock)
        view.refresh(client)
        client.close()
    lines = view.lines(200)
    i = lines.index("t1  gsLlenar")
    assert lines[i + 1] == "  Depósito 1; gsLlenar: filling the tank"
    assert "iNivel=0cm" in lines[i + 2], lines
    assert os.path.exists(tmp_path / "tank.yaml")
