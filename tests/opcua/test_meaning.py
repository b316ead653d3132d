"""What an HMI integrator reads besides values (issue 29), with asyncua's client against
the server fed by a running controller: the I/O list of the drawer tester plant of
configs/ (Spanish descriptions, the point -> signal references, the unit of a step's
time), units and ranges of numbers (EngineeringUnits with UN/CEFACT codes, EURange), and
UserAccessLevel as the session may act (anonymous and readers: read only)."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from asyncua import Client, ua

from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import ServerThread, serving, wait_shown
from tests.opcua.kit import drawer_plant, free_port, writer

CEFACT = "http://www.opcfoundation.org/UA/units/un/cefact"


@contextmanager
def served(path: Path) -> Iterator[ServerThread]:
    pdef = load_plant(str(path))
    with serving(pdef), ServerThread(pdef) as srv:
        wait_shown(srv)
        yield srv


async def describe(c: Client, name: str) -> str:
    return str((await c.get_node(f"ns=2;s={name}").read_description()).Text)


async def prop(c: Client, name: str, leaf: str) -> Any:
    node = await c.get_node(f"ns=2;s={name}").get_child(f"2:{leaf}")
    return await node.read_value()


def test_the_drawer_testers_io_list_through_opc_ua(tmp_path: Path) -> None:
    with served(drawer_plant(tmp_path)) as srv:
        async def main() -> dict[str, Any]:
            async with Client(srv.url) as c:
                bound = ua.NodeId("BoundSignal", 2)
                point = c.get_node("ns=2;s=sim.I0")
                signals = await point.get_referenced_nodes(bound, ua.BrowseDirection.Forward)
                back = await c.get_node("ns=2;s=tester1.oAbrir").get_referenced_nodes(
                    bound, ua.BrowseDirection.Inverse)
                eu = await prop(c, "tester1.gsAbrir.T", "EngineeringUnits")
                return {
                    "iParo": await describe(c, "tester1.iParo"),
                    "oAbrir": await describe(c, "tester2.oAbrir"),
                    "tester1": await describe(c, "tester1"),
                    "sim.I0": await describe(c, "sim.I0"),
                    "gsAbrir": await describe(c, "tester1.gsAbrir"),
                    "gsAbrir.T": await describe(c, "tester1.gsAbrir.T"),
                    "signals": [n.nodeid.to_string() for n in signals],
                    "back": [n.nodeid.to_string() for n in back],
                    "eu": (eu.NamespaceUri, eu.UnitId, eu.DisplayName.Text),
                    "ref name": (await c.get_node(bound).read_browse_name()).Name,
                }
            raise AssertionError("unreachable")
        got = asyncio.run(main())
    assert got["iParo"] == "Pulsador de paro SJP (NC)"
    assert got["oAbrir"] == "Contactor QAA, abrir el cajón"
    assert got["tester1"] == "Banco de ensayo de guías de cajón 1"
    assert got["sim.I0"] == "-> tester1.iParo (NC, inverted): Pulsador de paro SJP (NC)"
    assert got["gsAbrir"] == "Opening the drawer"
    assert got["gsAbrir.T"] == "Opening the drawer: time the step has been active, ms"
    assert got["signals"] == ["ns=2;s=tester1.iParo"]
    assert got["back"] == ["ns=2;s=sim.Q0"]
    assert got["eu"] == (CEFACT, 4403766, "ms")  # C26, millisecond
    assert got["ref name"] == "BoundSignal"


TANK = """\
grafcet: Tank
inputs:
  - {iNivel: real}
  - {iCaudal: int}
outputs: [oBomba]
memory:
  sConsigna: {init: 50.0, description: level set point}
steps:
  gsVacio: {initial: true}
  gsLleno: {}
transitions:
  - {from: gsVacio, to: gsLleno, when: "iNivel >= sConsigna"}
  - {from: gsLleno, to: gsVacio, when: "iNivel < 10.0"}
post:
  - oBomba := gsVacio.X
"""


def test_units_and_ranges_of_numbers(tmp_path: Path) -> None:
    (tmp_path / "tank.yaml").write_text(TANK, encoding="utf-8")
    path = tmp_path / "plant.yaml"
    path.write_text(
        "drivers:\n  io: {type: sim}\ninstances:\n  t1:\n    grafcet: tank.yaml\n"
        "    inputs:\n"
        "      iNivel:  {from: io.level, unit: cm, range: [0, 150], description: LT1}\n"
        "      iCaudal: {from: io.flow, unit: l/min}\n"
        "    outputs: {oBomba: io.Q0}\n"
        f"opcua:\n  endpoint: opc.tcp://127.0.0.1:{free_port()}\n  feed: {tmp_path}/feed.sock\n"
        "  security: {policies: [None]}\n", encoding="utf-8")
    with served(path) as srv:
        async def main() -> dict[str, Any]:
            async with Client(srv.url) as c:
                eu = await prop(c, "t1.iNivel", "EngineeringUnits")
                rng = await prop(c, "t1.iNivel", "EURange")
                flow = await prop(c, "t1.iCaudal", "EngineeringUnits")
                level = await describe(c, "io.level")
                kids = [(await n.read_browse_name()).Name
                        for n in await c.get_node("ns=2;s=t1.iCaudal").get_children()]
                return {"eu": (eu.NamespaceUri, eu.UnitId, eu.DisplayName.Text,
                               eu.Description.Text),
                        "range": (rng.Low, rng.High), "flow": (flow.UnitId,
                                                                flow.DisplayName.Text),
                        "level": level, "flow children": kids,
                        "memory": await describe(c, "t1.sConsigna")}
            raise AssertionError("unreachable")
        got = asyncio.run(main())
    assert got["eu"] == (CEFACT, 4410708, "cm", "centimetre")  # CMT
    assert got["range"] == (0.0, 150.0)
    assert got["flow"] == (19506, "l/min")  # L2
    assert got["flow children"] == ["EngineeringUnits"]  # no range given: no EURange
    assert got["level"] == "-> t1.iNivel: LT1"  # the point says what it is bound to
    assert got["memory"] == "level set point"


def test_user_access_level_tells_each_session_what_it_may_do(tmp_path: Path) -> None:
    """Before, an anonymous session read UserAccessLevel 3 (read + write) on a writable
    name, then its write failed: a panel showed an editable field that always fails."""
    with served(drawer_plant(tmp_path)) as srv:
        async def levels(c: Client) -> dict[str, set[ua.AccessLevel]]:
            return {n: set(await c.get_node(f"ns=2;s={n}").get_user_access_level())
                    for n in ("tester1.sParo", "tester1.sCierres", "tester2.sParo")}

        async def main() -> tuple[Any, Any, Any]:
            async with Client(srv.url) as anon:
                a = await levels(anon)
                plain = set(await anon.get_node("ns=2;s=tester1.sParo").get_access_level())
            async with writer(srv.url) as w:
                b = await levels(w)
            return a, b, plain
        anonymous, written, access = asyncio.run(main())
    read, write = ua.AccessLevel.CurrentRead, ua.AccessLevel.CurrentWrite
    assert anonymous == {"tester1.sParo": {read}, "tester1.sCierres": {read},
                         "tester2.sParo": {read}}
    assert written == {"tester1.sParo": {read, write}, "tester1.sCierres": {read},
                       "tester2.sParo": {read}}
    assert access == {read, write}  # AccessLevel: what the node allows someone
