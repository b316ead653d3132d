"""The console's ``web USER ADDRESS`` (docs/console.md): only on a plant with ``web:``,
once per session, with words that can go into a log line; the session then acts without
a PIN under the name ``web:USER@ADDRESS``."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.console.consolekit import make_rig
from tests.web.kit import rig


def test_web_is_refused_on_a_plant_without_a_web_section() -> None:
    r = make_rig(serial_port=False, trusted=False)
    try:
        c = r.connect()
        assert c.error("web op 127.0.0.1") == "web: the plant has no web: section"
    finally:
        r.close()


def test_web_names_the_session_once_and_lets_it_act(tmp_path: Path) -> None:
    with rig(tmp_path) as r:
        out = r.console("force tester1.oTest 1", "web other x", "unforce tester1.oTest")
        assert out == ["acting for web:test@local", "ok", "tester1.oTest forced to 1", "ok",
                       "error web: this session already acts for web:test@local",
                       "tester1.oTest released", "ok"]
        assert r.console("web a;b x", "force tester1.oTest 1", act=False) == [
            "error usage: web USER ADDRESS", "error changing commands are disabled on this "
            "console: no pin_hash in the plant file and the console is not trusted"]
        log = r.ctl.log()
        assert "acts for web:test@local" in log
        assert "console web:test@local: force tester1.oTest" in log, log


def test_a_login_that_times_out_ends_in_the_safe_reaction(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``web: idle_logout`` (10 min by default) on the web view's clock, stepped by the
    test: the page's force dies with its login, as a console session's (halted, every
    output off, the console's log line)."""
    import asyncio
    import json

    import aiohttp

    from runtime.language.plantfile import load_plant
    from runtime.web.server import WebView
    from tests.opcua.feedkit import wait_until
    from tests.web.kit import PASSWORD, USER

    with rig(tmp_path) as r:
        monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # where the controller runs
        pdef = load_plant(str(r.plant))
        now = [1000.0]

        async def run() -> str:
            view = WebView(pdef, clock=lambda: now[0])
            stop = asyncio.Event()
            ports: list[int] = []
            task = asyncio.create_task(view.run(stop, lambda v, p: ports.append(p)))
            for _ in range(3000):
                if ports and view.feed.state.values:
                    break
                await asyncio.sleep(0.01)
            assert view.feed.state.values, "the web view did not reach the feed"
            url = f"http://127.0.0.1:{ports[0]}"
            jar = aiohttp.CookieJar(unsafe=True)  # keeps the cookie of 127.0.0.1
            async with aiohttp.ClientSession(cookie_jar=jar) as s:
                async with s.post(url + "/api/login", json={"user": USER,
                                                            "password": PASSWORD},
                                  headers={"Origin": url}) as resp:
                    assert resp.status == 200
                ws = await s.ws_connect(url + "/ws", headers={"Origin": url})
                await ws.send_str(json.dumps({"act": [1, "force", "tester1.oTest", "1"]}))
                while True:
                    msg = json.loads((await ws.receive()).data)
                    if msg["t"] == "r":
                        assert msg["ok"], msg
                        break
                await asyncio.to_thread(wait_until, lambda: r.value("sim.Q3") is True, 30.0)
                now[0] += 601.0  # ten minutes without an action
                while True:
                    msg = json.loads((await ws.receive()).data)
                    if msg["t"] == "logout":
                        why = str(msg["why"])
                        break
                await ws.close()
            stop.set()
            await task
            return why
        why = asyncio.run(run())
        assert why == "no action for 600 s (web: idle_logout)"
        wait_until(lambda: r.status().get("state") == "halted", 30.0, "the safe reaction")
        wait_until(lambda: not any(r.value(f"sim.Q{i}") for i in range(8)), 10.0, "off")
        assert "web:op@127.0.0.1" in r.ctl.log()
