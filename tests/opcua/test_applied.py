"""After the safe reaction, an OPC UA client reads the outputs the machine has.

Issue: the controller halted (a console session holding a force ended) and every output
point went to 0, but the displays kept the stopped chart's value (an output read 1). The
server's values come from the feed, which reads a chart output as applied (its point,
through the binding: runtime/engine/names.py); asyncua's client over TCP reads it off."""

from __future__ import annotations

import asyncio
from pathlib import Path

from asyncua import Client

from runtime.language.plantfile import load_plant
from tests.opcua.feedkit import ServerThread, serving, until, wait_shown
from tests.opcua.kit import drawer_plant


def test_an_output_reads_off_while_the_outputs_are_held_off(tmp_path: Path) -> None:
    path = drawer_plant(tmp_path)
    # no freeze of a loaded machine taken for a fault: the halt is the test's
    path.write_text(path.read_text(encoding="utf-8").replace("watchdog: 100ms", "watchdog: 5s"),
                    encoding="utf-8")
    pdef = load_plant(str(path))
    assert pdef.watchdog_ns == 5_000_000_000
    with serving(pdef) as (d, _feed), ServerThread(pdef) as srv:
        wait_shown(srv)

        async def main() -> tuple[bool, bool, str, bool, int]:
            async with Client(srv.url) as c:
                lamp = c.get_node("ns=2;s=tester1.oParado")  # gsParado active: on
                state = c.get_node("ns=2;s=controller.state")
                await until(lambda: lamp.read_value(), 20, "tester1.oParado on")
                before = await lamp.read_value()
                d.require_ack("console test ended (peer disconnected) while it held: "
                              "force tester1.oTest")
                await until(lambda: _is(state, "halted"), 20, "the halt in OPC UA")
                # a frame after the halt: the server shows what the feed last sent
                scan = await c.get_node("ns=2;s=controller.scan").read_value()
                await until(lambda: _after(c, scan), 20, "a frame after the halt")
                after = await lamp.read_value()
                point = await c.get_node("ns=2;s=sim.Q2").read_value()
                return (before, after, await state.read_value(),
                        bool(d.call(lambda: d.plant.get("tester1.oParado"))), int(point))
        before, after, state, chart, point = asyncio.run(main())
    assert before is True
    assert state == "halted" and chart is True and point == 0  # the chart says 1, held off
    assert after is False, "OPC UA showed the stopped chart's 1, not the output"


async def _is(node: object, value: str) -> bool:
    return bool(await node.read_value() == value)  # type: ignore[attr-defined]


async def _after(c: Client, scan: int) -> bool:
    return bool(await c.get_node("ns=2;s=controller.scan").read_value() > scan + 1)
