"""Clients of ``softplc web`` run as processes of their own, as machines on the bench
network would be (the CPU and the GIL they need are not the controller's when it runs in
the test's process): hostile ones, and an operator.

    python -m tests.web.clients flood HOST PORT COUNT ADDRESSES SECONDS
        COUNT half-sent requests (a request line and one header, never the blank line
        that ends them) from ADDRESSES loopback source addresses (127.0.0.2 ...), each
        opened again as soon as the server closes it, for SECONDS
    python -m tests.web.clients logins URL SECONDS ADDRESSES USER
        from each of ADDRESSES loopback source addresses (127.0.0.2 ...), wrong
        passwords for USER posted as fast as the replies come, for SECONDS (the posts
        still waiting then are given up)
    python -m tests.web.clients deep URL SECONDS
        one page's WebSocket sending JSON nested 2000 deep as fast as the replies come
    python -m tests.web.clients frozen URL USER PASSWORD NAME
        logs in, forces NAME to 1 from its page, prints {"forced": ...}, then reads its
        WebSocket until it is stopped (SIGSTOP: a laptop gone to sleep) or killed
    python -m tests.web.clients operator URL USER PASSWORD
        logs in, reads its page's WebSocket, acts every 0.25 s (set tester1.sCierres K)
        and loads a fresh page (/api/plant on a new connection) every second; each
        "take" on stdin prints its counts since the last (frames, acts, acted, loads,
        loaded, failures; the longest an action and a load took, s), "stop" ends it

Each hostile one waits for "go" on stdin after printing {"ready": ...} (the frozen one
excepted), and prints one JSON object with what it did and saw.
"""

from __future__ import annotations

import asyncio
import errno
import json
import select
import socket
import sys
import threading
import time
from typing import Any

import aiohttp

#: JSON nested this deep: 4000 bytes, within the page's 4096-byte messages
DEEP = "[" * 2000 + "]" * 2000


def source(i: int) -> str:
    """The i-th loopback source address of the attackers (127.0.0.2 ... 127.0.0.251)."""
    assert 0 <= i < 250
    return f"127.0.0.{i + 2}"


def _say(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _ready(what: Any) -> None:
    _say({"ready": what})
    line = sys.stdin.readline()
    assert line.strip() == "go", line


def flood(host: str, port: int, count: int, addresses: int, seconds: float) -> dict[str, Any]:
    request = (f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\n").encode()
    socks: dict[int, tuple[socket.socket, int]] = {}
    poll = select.poll()
    stats: dict[str, int] = {"opened": 0, "refused": 0, "closed_by_server": 0}
    errors: dict[str, int] = {}

    def open_one(i: int) -> None:
        s = socket.socket()
        s.settimeout(2.0)
        try:
            s.bind((source(i % addresses), 0))
            s.connect((host, port))
            s.sendall(request)
        except OSError as exc:
            s.close()
            stats["refused"] += 1
            name = errno.errorcode.get(exc.errno or 0, type(exc).__name__)
            errors[name] = errors.get(name, 0) + 1
            return
        s.setblocking(False)
        socks[s.fileno()] = (s, i)
        poll.register(s, select.POLLIN | select.POLLHUP | select.POLLERR)
        stats["opened"] += 1

    for i in range(count):
        open_one(i)
    _ready({"opened": stats["opened"], "refused": stats["refused"]})
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for fd, _ev in poll.poll(100):
            s, i = socks.pop(fd)
            poll.unregister(fd)
            s.close()
            stats["closed_by_server"] += 1
            open_one(i)  # at once: the pressure stays
    stats["open_at_end"] = len(socks)
    for s, _i in socks.values():
        s.close()
    return {**stats, "errors": errors}


async def logins(url: str, seconds: float, addresses: int, user: str) -> dict[str, Any]:
    statuses: dict[str, int] = {}
    origin = url.rstrip("/")

    async def one(i: int, end: float) -> None:
        conn = aiohttp.TCPConnector(local_addr=(source(i), 0))
        async with aiohttp.ClientSession(connector=conn) as s:
            n = 0
            while time.monotonic() < end:
                n += 1
                async with s.post(url + "api/login", json={"user": user,
                                                           "password": f"guess{n}"},
                                  headers={"Origin": origin}) as resp:
                    await resp.read()
                    statuses[str(resp.status)] = statuses.get(str(resp.status), 0) + 1
    _ready(addresses)
    end = time.monotonic() + seconds
    tasks = [asyncio.create_task(one(i, end)) for i in range(addresses)]
    _done, pending = await asyncio.wait(tasks, timeout=seconds)
    for t in pending:  # the guesses still waiting for their hash are given up
        t.cancel()
    await asyncio.gather(*pending, return_exceptions=True)
    return {"statuses": statuses, "posts": sum(statuses.values()),
            "given_up": len(pending)}


async def deep(url: str, seconds: float) -> dict[str, Any]:
    origin = url.rstrip("/")
    out: dict[str, Any] = {"sent": 0, "malformed": 0, "closed": False}
    async with aiohttp.ClientSession() as s:
        ws = await s.ws_connect(url + "ws", headers={"Origin": origin})
        _ready(True)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            await ws.send_str(DEEP)
            out["sent"] += 1
            while True:
                msg = await ws.receive()
                if msg.type is not aiohttp.WSMsgType.TEXT:
                    out["closed"] = True
                    return out
                data = json.loads(msg.data)
                if data["t"] == "r":
                    out["malformed"] += data["text"] == "malformed message"
                    break
        await ws.close()
    return out


async def frozen(url: str, user: str, password: str, name: str) -> None:
    origin = url.rstrip("/")
    jar = aiohttp.CookieJar(unsafe=True)
    async with aiohttp.ClientSession(cookie_jar=jar) as s:
        async with s.post(url + "api/login", json={"user": user, "password": password},
                          headers={"Origin": origin}) as resp:
            assert resp.status == 200, await resp.text()
        ws = await s.ws_connect(url + "ws", headers={"Origin": origin})
        await ws.send_str(json.dumps({"act": [1, "force", name, "1"]}))
        while True:
            msg = await ws.receive()
            data = json.loads(msg.data)
            if data["t"] == "r":
                _say({"forced": data})
                break
        while not ws.closed:  # reading: it answers the server's pings, until stopped
            msg = await ws.receive()
            if msg.type is not aiohttp.WSMsgType.TEXT:
                break


async def operator(url: str, user: str, password: str) -> None:
    origin = url.rstrip("/")
    counts: dict[str, Any] = {"failures": []}
    loop = asyncio.get_running_loop()
    orders: asyncio.Queue[str] = asyncio.Queue()

    def add(key: str, n: int = 1) -> None:
        counts[key] = counts.get(key, 0) + n

    def slowest(key: str, seconds: float) -> None:
        counts[key] = round(max(counts.get(key, 0.0), seconds), 3)

    def stdin() -> None:
        for line in sys.stdin:
            loop.call_soon_threadsafe(orders.put_nowait, line.strip())
        loop.call_soon_threadsafe(orders.put_nowait, "stop")
    jar = aiohttp.CookieJar(unsafe=True)
    async with aiohttp.ClientSession(cookie_jar=jar) as s:
        async with s.post(url + "api/login", json={"user": user, "password": password},
                          headers={"Origin": origin}) as resp:
            assert resp.status == 200, await resp.text()
        ws = await s.ws_connect(url + "ws", headers={"Origin": origin})
        replies: asyncio.Queue[dict[str, Any]] = asyncio.Queue()

        async def read() -> None:
            async for msg in ws:
                data = json.loads(msg.data)
                if data["t"] in ("d", "f"):
                    add("frames")
                elif data["t"] == "r":
                    replies.put_nowait(data)

        async def act() -> None:
            k, last_load = 0, 0.0
            while True:
                k += 1
                await ws.send_str(json.dumps({"act": [k, "set", "tester1.sCierres",
                                                      str(k % 1000)]}))
                t0 = time.monotonic()
                try:
                    got = await asyncio.wait_for(replies.get(), 10)
                    slowest("act_max_s", time.monotonic() - t0)
                    add("acts")
                    add("acted", got["ok"] is True)
                    if not got["ok"]:
                        counts["failures"].append(str(got))
                except TimeoutError:
                    add("acts")
                    counts["failures"].append("no reply to an action in 10 s")
                if time.monotonic() - last_load >= 1.0:
                    last_load = time.monotonic()
                    # a load is counted when it ends, tried and loaded together: one that
                    # straddles a "take" belongs wholly to the next phase (counted when it
                    # began, it was a load of one phase and a page loaded in the next)
                    try:
                        async with aiohttp.ClientSession() as fresh, fresh.get(
                                url + "api/plant", timeout=aiohttp.ClientTimeout(10)) as r:
                            add("loads")
                            add("loaded", r.status == 200)
                            slowest("load_max_s", time.monotonic() - last_load)
                    except (aiohttp.ClientError, TimeoutError) as exc:
                        add("loads")
                        counts["failures"].append(f"load: {exc!r}")
                await asyncio.sleep(0.25)
        tasks = [asyncio.create_task(read()), asyncio.create_task(act())]
        threading.Thread(target=stdin, daemon=True).start()
        _say({"ready": True})
        while (order := await orders.get()) != "stop":
            if order == "take":
                _say(counts)
                counts = {"failures": []}
        for t in tasks:
            t.cancel()
        await ws.close()


def main(argv: list[str]) -> None:
    mode, *args = argv
    out: dict[str, Any]
    if mode == "flood":
        host, port, count, addresses, seconds = args
        out = flood(host, int(port), int(count), int(addresses), float(seconds))
    elif mode == "logins":
        url, seconds, addresses, user = args
        out = asyncio.run(logins(url, float(seconds), int(addresses), user))
    elif mode == "deep":
        url, seconds = args
        out = asyncio.run(deep(url, float(seconds)))
    elif mode == "frozen":
        asyncio.run(frozen(*args))
        return
    elif mode == "operator":
        asyncio.run(operator(*args))
        return
    else:
        raise SystemExit(f"unknown mode {mode}")
    _say(out)


if __name__ == "__main__":
    main(sys.argv[1:])
