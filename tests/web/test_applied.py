"""After the safe reaction, the page's I/O list shows the outputs the machine has.

Issue: the page holding a force was closed; the controller halted and the output's point
went to 0, but the page's I/O list row (``tank.oMixer out sim.Q2 1``) still showed 1, the
stopped chart's value. The page's rows take their values from the web view's frames, which
come from the feed, which reads a chart output as applied (its point, through the binding:
runtime/engine/names.py). The issue's own steps: a page logs in, forces, is closed."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import aiohttp

from tests.opcua.feedkit import wait_until
from tests.web.kit import PASSWORD, USER, rig


async def page_frame(url: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """What a page newly opened gets: (the controller's status, name -> value)."""
    async with aiohttp.ClientSession() as s:
        ws = await s.ws_connect(url + "ws", headers={"Origin": url.rstrip("/")})
        status: dict[str, Any] = {}
        while True:
            msg = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
            if msg["t"] == "s":
                status = msg["status"]
            if msg["t"] == "f":
                await ws.close()
                return status, dict(zip(msg["names"], msg["values"], strict=True))


async def force_then_close(url: str, name: str, seen: Any) -> None:
    """A logged-in page forces ``name`` to 1, waits until its point is on, and is closed
    (its console session ends while it holds the force: the safe reaction)."""
    origin = url.rstrip("/")
    jar = aiohttp.CookieJar(unsafe=True)
    async with aiohttp.ClientSession(cookie_jar=jar) as s:
        async with s.post(url + "api/login", json={"user": USER, "password": PASSWORD},
                          headers={"Origin": origin}) as resp:
            assert resp.status == 200
        ws = await s.ws_connect(url + "ws", headers={"Origin": origin})
        await ws.send_str(json.dumps({"act": [1, "force", name, "1"]}))
        while True:
            msg = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
            if msg["t"] == "r":
                assert msg["ok"], msg
                break
        for _ in range(3000):  # the point on: the force went through a scan
            if seen():
                break
            await asyncio.sleep(0.01)
        await ws.close()


def test_after_the_page_holding_a_force_is_closed_its_rows_show_the_outputs_off(
        tmp_path: Path) -> None:
    with rig(tmp_path) as r:
        point = "sim.Q3"  # tester1.oTest
        asyncio.run(force_then_close(r.url, "tester1.oTest", lambda: r.value(point) == 1))
        wait_until(lambda: r.status().get("state") == "halted", 30, "the halt")
        wait_until(lambda: r.value(point) == 0, 30, "the point off")
        status, values = asyncio.run(page_frame(r.url))
    assert status["state"] == "halted"
    assert values[point] == 0
    assert values["tester1.oTest"] == 0, "the page's row showed the stopped chart's 1"
    assert values["tester1.oParado"] == 0  # gsParado active: the chart says 1, held off
