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



def test_each_login_ends_once_and_is_told_apart_when_the_web_view_stops(
        tmp_path: Path) -> None:
    """SIGTERM said ``web: op's login from 127.0.0.1 ended`` twice: once per login, the
    lines alike. Each login has its number in its lines; a browser logging in again
    retires its previous login (no page open on it) at once; a page still open keeps its
    own."""
    import asyncio
    import json
    import signal

    import aiohttp

    from tests.web.kit import PASSWORD, USER

    with rig(tmp_path) as r:
        url = r.url.rstrip("/")

        async def log_in(s: aiohttp.ClientSession) -> None:
            async with s.post(url + "/api/login", json={"user": USER, "password": PASSWORD},
                              headers={"Origin": url}) as resp:
                assert resp.status == 200

        async def run() -> None:
            # cookie jars keeping 127.0.0.1's cookie: two browsers
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as a, \
                    aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as b:
                await log_in(a)
                await log_in(a)  # the same browser again: login 1 is retired
                await log_in(b)
                ws = await b.ws_connect(url + "/ws", headers={"Origin": url})
                await ws.send_str(json.dumps({"act": [1, "pause"]}))
                while True:  # the page acts: its console session is open
                    msg = json.loads((await ws.receive()).data)
                    if msg["t"] == "r":
                        assert msg["ok"], msg
                        break
                r.web.popen.send_signal(signal.SIGTERM)
                while (await ws.receive()).type not in (
                        aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                        aiohttp.WSMsgType.ERROR):
                    pass
        asyncio.run(run())
        r.web.popen.wait(timeout=30)
    log = r.web.log()
    said = [ln.split(": ", 1)[1] for ln in r.web.lines if "runtime.web.server: web: op" in ln]
    assert said == [
        "web: op logged in from 127.0.0.1 (login 1)",
        "web: op's login 1 from 127.0.0.1 ended (replaced by a new login from the same "
        "browser)",
        "web: op logged in from 127.0.0.1 (login 2)",
        "web: op logged in from 127.0.0.1 (login 3)",
        "web: op's login 2 from 127.0.0.1 ended (the web view stops)",
        "web: op's login 3 from 127.0.0.1 ended (the web view stops)"], log
