"""Hostile clients of ``softplc web`` (docs/web.md, "Security"): a WebSocket and a login
from another origin, state changes by GET, 200 connections at once, pages beyond
``max_pages``, oversized messages and bodies, slow readers. The server bounds each; the
controller sees nothing (no console session, no feed client, no log line, still running)."""

from __future__ import annotations

import asyncio
import json
import shutil
import socket
import ssl
import subprocess
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from runtime.language.plantfile import load_plant
from runtime.web import server as web_server
from runtime.web.server import WebView
from tests.web.kit import PASSWORD, USER, Rig, rig, write_plant


@asynccontextmanager
async def served(pdef: Any, tmp: Path) -> AsyncIterator[tuple[WebView, int]]:
    """A WebView of ``pdef`` in this event loop, with no controller: (view, its port)."""
    view = WebView(pdef, feed=str(tmp / "no-feed.sock"))
    stop = asyncio.Event()
    ports: list[int] = []
    task = asyncio.create_task(view.run(stop, lambda v, p: ports.append(p)))
    while not ports:
        await asyncio.sleep(0.01)
    try:
        yield view, ports[0]
    finally:
        stop.set()
        await task


def origin(r: Rig) -> str:
    return r.url.rstrip("/")


async def ws_status(r: Rig, origin_header: str | None) -> int:
    """The HTTP status of a WebSocket handshake with this Origin (101 when accepted)."""
    headers = {"Origin": origin_header} if origin_header else {}
    async with aiohttp.ClientSession() as s:
        try:
            ws = await s.ws_connect(r.url + "ws", headers=headers)
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status
        await ws.close()
        return 101


def controller_untouched(r: Rig, lines_before: int) -> None:
    """The controller still runs, and its log got nothing from the attack."""
    assert r.status()["state"] == "running"
    new = r.ctl.lines[lines_before:]
    assert not [ln for ln in new if "console" in ln or "feed" in ln], new


def test_other_origins_and_gets_change_nothing(tmp_path: Path) -> None:
    with rig(tmp_path) as r:
        before = len(r.ctl.lines)
        assert asyncio.run(ws_status(r, "http://evil.example")) == 403
        assert asyncio.run(ws_status(r, None)) == 403
        assert asyncio.run(ws_status(r, origin(r))) == 101

        async def posts() -> list[int]:
            async with aiohttp.ClientSession() as s:
                out = []
                body = json.dumps({"user": "op", "password": "x"})
                for hdrs in ({"Origin": "http://evil.example",
                              "Content-Type": "application/json"},
                             {"Origin": origin(r), "Content-Type": "text/plain"},
                             {"Content-Type": "application/x-www-form-urlencoded"}):
                    async with s.post(r.url + "api/login", data=body, headers=hdrs) as resp:
                        out.append(resp.status)
                async with s.get(r.url + "api/login") as resp:
                    out.append(resp.status)
                async with s.get(r.url + "api/logout") as resp:
                    out.append(resp.status)
                async with s.get(r.url) as resp:
                    csp = resp.headers["Content-Security-Policy"]
                    assert "script-src 'self'" in csp and "unsafe-inline" not in csp
                    assert resp.headers["X-Frame-Options"] == "DENY"
                return out
        assert asyncio.run(posts()) == [403, 415, 403, 405, 405]
        assert "refused" in r.web.log() and "evil.example" in r.web.log()
        controller_untouched(r, before)


def test_two_hundred_connections_and_more_pages_than_allowed(tmp_path: Path) -> None:
    with rig(tmp_path, web="  max_pages: 5\n") as r:
        before = len(r.ctl.lines)
        host, port = r.url.split("//")[1].rstrip("/").split(":")
        idle = []
        for i in range(200):  # connections that never send a request, from 4 addresses
            s = socket.create_connection((host, int(port)),
                                         source_address=(f"127.0.0.{2 + i % 4}", 0))
            idle.append(s)

        async def pages() -> tuple[list[int], int]:
            async with aiohttp.ClientSession() as s:
                opened: list[Any] = []
                statuses = []
                for _ in range(8):
                    try:
                        opened.append(await s.ws_connect(
                            r.url + "ws", headers={"Origin": origin(r)}))
                        statuses.append(101)
                    except aiohttp.WSServerHandshakeError as exc:
                        statuses.append(exc.status)
                # the open pages are fed: each gets a frame
                got = 0
                for ws in opened:
                    while True:
                        msg = await asyncio.wait_for(ws.receive(), 30)
                        if json.loads(msg.data)["t"] in ("f", "d"):
                            got += 1
                            break
                async with s.get(r.url + "api/plant") as resp:  # the page still served
                    assert resp.status == 200
                for ws in opened:
                    await ws.close()
                return statuses, got
        statuses, got = asyncio.run(pages())
        assert statuses == [101] * 5 + [503] * 3 and got == 5
        for s in idle:
            s.close()
        controller_untouched(r, before)


def test_oversized_messages_and_bodies_are_refused(tmp_path: Path) -> None:
    with rig(tmp_path) as r:
        before = len(r.ctl.lines)

        async def attack() -> tuple[Any, int, int]:
            async with aiohttp.ClientSession() as s:
                ws = await s.ws_connect(r.url + "ws", headers={"Origin": origin(r)})
                await ws.send_str("x" * 100_000)
                while True:
                    msg = await asyncio.wait_for(ws.receive(), 30)
                    if msg.type in (aiohttp.WSMsgType.CLOSE, aiohttp.WSMsgType.CLOSED,
                                    aiohttp.WSMsgType.CLOSING, aiohttp.WSMsgType.ERROR):
                        break
                # the code of the server's close frame (aiohttp 3.14.5's client reports
                # ws.close_code 1006 once the server has closed the connection after it)
                code = msg.data if msg.type is aiohttp.WSMsgType.CLOSE else ws.close_code
                big = json.dumps({"user": "op", "password": "x" * 100_000})
                async with s.post(r.url + "api/login", data=big, headers={
                        "Origin": origin(r), "Content-Type": "application/json"}) as resp:
                    body_status = resp.status
                ws2 = await s.ws_connect(r.url + "ws", headers={"Origin": origin(r)})
                await ws2.send_str("not json")
                reply = None
                while reply is None:
                    msg = await asyncio.wait_for(ws2.receive(), 30)
                    data = json.loads(msg.data)
                    if data["t"] == "r":
                        reply = data
                await ws2.close()
                return code, body_status, reply["ok"]
        code, body_status, ok = asyncio.run(attack())
        assert code == aiohttp.WSCloseCode.MESSAGE_TOO_BIG
        assert body_status == 413 and ok is False
        controller_untouched(r, before)


def test_a_page_that_does_not_read_is_bounded_then_closed(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (no controller needed): a WebSocket client that never reads, on a
    small receive buffer. Its queue never holds more than PAGE_QUEUE messages (it is
    resynchronised instead), and once one send waits SEND_TIMEOUT_S it is closed (before
    the fix, the page was never closed: its close frame waited behind the unread data)."""
    monkeypatch.setattr(web_server, "SEND_TIMEOUT_S", 1.0)
    pdef = load_plant(str(write_plant(tmp_path)))

    async def run() -> tuple[int, int, int]:
        async with served(pdef, tmp_path) as (view, port):
            sock = socket.socket()
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            sock.connect(("127.0.0.1", port))
            sock.sendall((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n"
                          f"Origin: http://127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                          "Connection: Upgrade\r\n"
                          "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                          "Sec-WebSocket-Version: 13\r\n\r\n").encode())
            while not view.pages:
                await asyncio.sleep(0.01)
            page = next(iter(view.pages))
            most = 0
            big = json.dumps({"t": "d", "changes": ["x" * 60_000]})
            for _ in range(2000):  # frames faster than it reads: ~120 MB offered
                view._send(page, big)
                most = max(most, page.queue.qsize())
                await asyncio.sleep(0.001)
                if page not in view.pages:
                    break
            for _ in range(500):
                if page not in view.pages:
                    break
                await asyncio.sleep(0.01)
            closed = int(page not in view.pages)
            sock.close()
            return most, page.resyncs, closed
    most, resyncs, closed = asyncio.run(run())
    assert most <= web_server.PAGE_QUEUE and resyncs > 0 and closed == 1


def test_the_page_waits_for_a_controller_that_is_not_there(tmp_path: Path) -> None:
    """No controller: the page is served and says so (its socket gets hello, not
    connected); nothing is created at the feed's path."""
    pdef = load_plant(str(write_plant(tmp_path)))

    async def run() -> dict[str, Any]:
        async with served(pdef, tmp_path) as (_view, port), aiohttp.ClientSession() as s:
            url = f"http://127.0.0.1:{port}"
            ws = await s.ws_connect(url + "/ws", headers={"Origin": url})
            hello = json.loads((await ws.receive()).data)
            await ws.close()
        return dict(hello)
    hello = asyncio.run(run())
    assert hello == {"t": "hello", "connected": False, "user": None}
    assert not (tmp_path / "no-feed.sock").exists()


def test_https_with_the_documented_certificate(tmp_path: Path) -> None:
    """docs/web.md's openssl command makes the certificate; the page is served over HTTPS
    only, and the login cookie is Secure, HttpOnly, SameSite=Strict."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt",
                    "ec_paramgen_curve:P-256", "-nodes", "-days", "3650", "-subj",
                    "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
                    "-keyout", str(key), "-out", str(cert)], check=True, capture_output=True)
    plant = write_plant(tmp_path, web=f"  tls: {{certificate: {cert}, private_key: {key}}}\n")
    pdef = load_plant(str(plant))

    async def run() -> tuple[int, Any, str, int]:
        ctx = ssl.create_default_context(cafile=str(cert))
        async with served(pdef, tmp_path) as (_view, port), aiohttp.ClientSession() as s:
            url = f"https://127.0.0.1:{port}"
            async with s.post(url + "/api/login", json={"user": USER, "password": PASSWORD},
                              headers={"Origin": url}, ssl=ctx) as resp:
                status, cookie = resp.status, resp.cookies.get("softplc_session")
            async with s.get(url + "/", ssl=ctx) as resp:
                hsts = resp.headers.get("Strict-Transport-Security", "")
            try:  # plain HTTP on the same port is no page
                async with s.get(f"http://127.0.0.1:{port}/") as resp:
                    plain = resp.status
            except aiohttp.ClientError:
                plain = 0
        return status, cookie, hsts, plain
    status, cookie, hsts, plain = asyncio.run(run())
    assert status == 200 and cookie is not None and plain != 200
    assert cookie["secure"] and cookie["httponly"] and cookie["samesite"] == "Strict"
    assert hsts.startswith("max-age=")
