"""``softplc web PLANT``: the live view of a running plant in the browser (docs/web.md), a
process of its own fed by the controller's feed (the scan never waits for it).

- **Pages.** ``GET /`` serves the page (static/index.html, static/app.js, static/app.css:
  every asset served here, no CDN); ``/api/plant`` the plant's instances and I/O list
  (runtime/web/plantview.py); ``/chart/INSTANCE.svg`` the chart as ``softplc draw`` draws
  it; ``/ws`` the WebSocket of a page: the controller's status, the values, the
  transitions of every instance (the console's ``why``), pushed once per feed frame.
- **Fan-out.** One feed connection for every page. Each frame becomes one delta message
  (the values that changed since the previous frame), the same bytes for every page. Each
  page has a queue of PAGE_QUEUE messages: a page whose queue is full (a slow reader) loses
  the frames that wait in it (not its replies and notices) and gets a whole frame next; a
  send that takes SEND_TIMEOUT_S closes it.
- **Acting** (logged in only): over the page's WebSocket, each action becomes one console
  command on the page's own console session (runtime/web/consolelink.py): the console's
  ownership rules, limits and log lines hold. Closing the page, losing its WebSocket or its
  login timing out (``web: idle_logout``) ends that session.
- **Security** (docs/web.md): 127.0.0.1 unless ``web: listen`` says otherwise, and then
  HTTPS only (the plant loader refuses it without ``tls``); a request whose ``Host`` is
  not a name of this server is refused with 421 (DNS rebinding: runtime/web/hosts.py);
  session cookies ``HttpOnly``, ``SameSite=Strict``, ``Secure`` over HTTPS; a request
  that changes anything (login, logout) is a POST of JSON from this origin (``Origin``
  checked); the WebSocket's ``Origin`` checked; no state change by GET; a failed login
  holds that user's logins from that address, an unknown user costs a hash as a known
  one (runtime/controller/pin.py ``Passwords``); a Content-Security-Policy without inline
  script; request bodies and WebSocket messages at most MAX_BODY bytes, JSON nested
  deeper than the parser goes is a malformed message; at most ``web: max_pages`` pages at
  once; connections bounded per address and in all, a request's headers and body within
  HEADER_TIMEOUT_S (runtime/web/connections.py); a page that answers nothing for ``web:
  page_timeout`` is closed.
"""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from aiohttp import WSMsgType, web

from runtime.controller.aio import within
from runtime.controller.feedclient import FeedClient
from runtime.controller.pin import BUSY, HELD, OK, Passwords
from runtime.language.coverage import ChartCoverage
from runtime.language.model import PlantDef, WebDef
from runtime.language.runtimedir import locate
from runtime.web.connections import HEADER_TIMEOUT_S, Listener
from runtime.web.consolelink import ACTIONS, VALUE_RE, ConsoleLink, ConsoleUnavailable
from runtime.web.hosts import host_name, this_server
from runtime.web.plantview import chart_of, describe

log = logging.getLogger(__name__)

#: messages waiting for one page; more and the page is resynchronised (a whole frame)
PAGE_QUEUE = 32
#: a page that takes this long to take one message is closed, seconds
SEND_TIMEOUT_S = 10.0
#: the largest request body and WebSocket message accepted, bytes
MAX_BODY = 4096
#: the session cookie's name
COOKIE = "softplc_session"
#: how often logins are checked for idleness, seconds
IDLE_CHECK_S = 1.0
#: the feed's why is followed for at most this many instances (the feed's MAX_WHY)
WHY_MAX = 8
#: the Content-Security-Policy of every response: scripts and styles from files of this
#: origin only (no inline script), no framing
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
       "connect-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'")
STATIC = ("index.html", "app.js", "app.css")
TYPES = {"html": "text/html", "js": "text/javascript", "css": "text/css"}
#: a request for a host that is not this server is logged at most this often, s
HOST_LOG_EVERY_S = 10.0
#: of ``web: page_timeout``, the part after which a silent page is sent a ping (aiohttp's
#: heartbeat; it then waits half as long for the answer: the whole timeout in all)
PING_AFTER = 2.0 / 3.0


def loads(text: str | bytes) -> Any:
    """JSON; ValueError for what is not, JSON nested deeper than the parser goes included
    (its RecursionError is no ValueError)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise ValueError("JSON nested too deep") from None


def action_of(msg: Any) -> tuple[Any, str, list[str]]:
    """A page's message ``{"act": [ID, ACTION, ARG...]}`` -> (id, action, args); ValueError
    for any other shape (an id that is not a number or a short text, an argument that is
    not a text)."""
    if not isinstance(msg, dict) or not isinstance(msg.get("act"), list):
        raise ValueError("no act")
    act = msg["act"]
    if len(act) < 2 or not isinstance(act[1], str):
        raise ValueError("no action")
    ident, action, *args = act
    if isinstance(ident, str):
        if len(ident) > 64:
            raise ValueError("an id too long")
    elif ident is not None and not isinstance(ident, (int, float)):
        raise ValueError("an id that is not a number or a text")
    if not all(isinstance(a, str) for a in args):
        raise ValueError("arguments are texts")
    return ident, action, args


@dataclass(eq=False)
class Login:
    """A logged-in user's browser session (its cookie)."""

    user: str
    address: str
    #: monotonic seconds of the last login or action
    last: float
    pages: set[Page] = field(default_factory=set)
    #: the login's number since this web view started, in its log lines (a user may hold
    #: several logins: one per browser)
    number: int = 0


@dataclass(eq=False)
class Page:
    """One open page (its WebSocket)."""

    ws: web.WebSocketResponse
    address: str
    login: Login | None
    #: its connection (aborted when it does not read)
    transport: asyncio.Transport | None = None
    #: (kept when the page falls behind, the message)
    queue: asyncio.Queue[tuple[bool, str]] = field(
        default_factory=lambda: asyncio.Queue(PAGE_QUEUE))
    #: its next frame is a whole one
    fresh: bool = True
    console: ConsoleLink | None = None
    #: messages dropped for it (it read too slowly)
    resyncs: int = 0


class WebView:
    """The web view of one plant: the feed's client, the pages, the logins."""

    def __init__(self, pdef: PlantDef, feed: str | None = None,
                 clock: Callable[[], float] = time.monotonic,
                 coverage: list[ChartCoverage] | None = None) -> None:
        """``coverage``: the charts' coverage (``softplc web --coverage``), their drawings
        shaded by it."""
        assert pdef.web is not None
        self.pdef = pdef
        self.coverage = coverage
        self.conf: WebDef = pdef.web
        self.clock = clock
        self.tls = self.conf.certificate is not None
        self.passwords = Passwords(self.conf.users, clock)
        #: the names a request's Host may give (DNS rebinding)
        self.hosts = this_server(self.conf.host, self.conf.certificate, self.conf.hosts)
        #: the listening socket and its connections (run)
        self.listener: Listener | None = None
        self._host_logged = -HOST_LOG_EVERY_S
        self.logins: dict[str, Login] = {}
        self._logins_made = 0
        self.pages: set[Page] = set()
        where = locate(pdef)  # the controller's sockets, as every side process finds them
        self.feed = FeedClient(feed or where.feed or self.conf.feed, "web", self._on_schema,
                               self._on_frame, self._on_lost, plant=pdef)
        #: the console socket the acting pages connect to (a Unix socket: the console
        #: knows this process's user there, docs/web.md)
        self.console_path = next((c.address for c in pdef.consoles if c.kind == "socket"),
                                 None) if where.console else None
        self._plant_json = json.dumps(describe(pdef))
        self._charts: dict[str, str] = {}
        self._last_values: list[Any] = []
        self._last_status: Any = None
        self._last_whys: dict[str, Any] = {}
        #: counters (tests): pages refused for max_pages, resyncs, frames fanned out
        self.refused = 0
        self.frames = 0

    # -- the application ---------------------------------------------------------------
    def app(self) -> web.Application:
        app = web.Application(client_max_size=MAX_BODY, middlewares=[self._headers])
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/api/plant", self._plant)
        app.router.add_get("/chart/{instance}.svg", self._chart)
        app.router.add_post("/api/login", self._login)
        app.router.add_post("/api/logout", self._logout)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/favicon.ico", self._no_icon)
        return app

    @web.middleware
    async def _headers(self, request: web.Request, handler: Any) -> web.StreamResponse:
        if request.host not in self.hosts:
            resp: web.StreamResponse = self._other_host(request)
        else:
            conn = self.listener.begin(request.transport) if self.listener else None
            try:
                resp = await handler(request)
            finally:
                if self.listener is not None:
                    self.listener.end(conn)
        h = resp.headers
        h["Content-Security-Policy"] = CSP
        h["X-Content-Type-Options"] = "nosniff"
        h["Referrer-Policy"] = "no-referrer"
        h["X-Frame-Options"] = "DENY"
        h["Cache-Control"] = "no-store"
        if self.tls:
            h["Strict-Transport-Security"] = "max-age=31536000"
        return resp

    def _other_host(self, request: web.Request) -> web.Response:
        """421 for a request whose Host is not this server (a name of another site
        pointed at this address: DNS rebinding); one log line per HOST_LOG_EVERY_S."""
        now = time.monotonic()
        if now - self._host_logged >= HOST_LOG_EVERY_S:
            self._host_logged = now
            log.warning("web: a request from %s for host %r refused: not a name of this "
                        "server (web: hosts adds names; docs/web.md)", request.remote,
                        host_name(request.host)[:80])
        return web.Response(status=421, text="this server is not "
                                             f"{host_name(request.host)[:80]!r}")

    def _origin_ok(self, request: web.Request) -> bool:
        """Whether the request comes from a page of this server (its Origin is this
        scheme and host)."""
        origin = request.headers.get("Origin")
        scheme = "https" if self.tls else "http"
        return origin is not None and origin == f"{scheme}://{request.host}"

    def _login_of(self, request: web.Request) -> Login | None:
        token = request.cookies.get(COOKIE)
        return self.logins.get(token) if token else None

    def _may_read(self, request: web.Request) -> bool:
        return self.conf.read == "anyone" or self._login_of(request) is not None

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return await self._static_file("index.html")

    async def _no_icon(self, request: web.Request) -> web.StreamResponse:
        return web.Response(status=204)

    async def _static(self, request: web.Request) -> web.StreamResponse:
        name = request.match_info["name"]
        if name not in STATIC:
            raise web.HTTPNotFound()
        return await self._static_file(name)

    async def _static_file(self, name: str) -> web.StreamResponse:
        data = resources.files("runtime.web").joinpath("static", name).read_bytes()
        kind = TYPES[name.rsplit(".", 1)[1]]
        return web.Response(body=data, content_type=kind, charset="utf-8")

    async def _plant(self, request: web.Request) -> web.StreamResponse:
        if not self._may_read(request):
            raise web.HTTPUnauthorized(text="log in to see this plant")
        login = self._login_of(request)
        body = json.dumps({"plant": json.loads(self._plant_json),
                           "user": login.user if login else None,
                           "may_act": bool(self.conf.users) and self.console_path is not None,
                           "read": self.conf.read})
        return web.Response(text=body, content_type="application/json")

    async def _chart(self, request: web.Request) -> web.StreamResponse:
        if not self._may_read(request):
            raise web.HTTPUnauthorized(text="log in to see this plant")
        name = request.match_info["instance"]
        svg = self._charts.get(name)
        if svg is None:
            svg = await asyncio.to_thread(chart_of, self.pdef, name, self.coverage)
            if svg is None:
                raise web.HTTPNotFound(text=f"no instance {name}")
            self._charts[name] = svg
        return web.Response(text=svg, content_type="image/svg+xml")

    async def _json_post(self, request: web.Request) -> dict[str, Any]:
        """The JSON object of a POST from a page of this server; HTTP errors otherwise
        (a form posted from another site has another Origin and no JSON type)."""
        if not self._origin_ok(request):
            raise web.HTTPForbidden(text="cross-origin request refused")
        if request.content_type != "application/json":
            raise web.HTTPUnsupportedMediaType(text="expected application/json")
        try:
            body = loads(await within(request.read(), HEADER_TIMEOUT_S))
        except TimeoutError:
            raise web.HTTPRequestTimeout(text="the request's body did not come") from None
        except ValueError:
            raise web.HTTPBadRequest(text="expected a JSON object") from None
        if not isinstance(body, dict):
            raise web.HTTPBadRequest(text="expected a JSON object")
        return body

    async def _login(self, request: web.Request) -> web.StreamResponse:
        body = await self._json_post(request)
        user, password = body.get("user"), body.get("password")
        address = request.remote or "?"
        if not isinstance(user, str) or not isinstance(password, str) or len(password) > 256:
            raise web.HTTPBadRequest(text="expected user and password")
        verdict = await asyncio.to_thread(self.passwords.verify, user, password, address)
        if verdict != OK:
            why = {HELD: "held after a failed one from there",
                   BUSY: "another login from there is being checked"}
            log.warning("web: login of '%s' from %s refused (%s)", user[:32], address,
                        why.get(verdict, "wrong user or password"))
            return web.json_response({"ok": False, "error": "wrong user or password (a "
                                      "failed login holds that user for 1 s from where "
                                      "it came)"}, status=403)
        old = request.cookies.get(COOKIE)
        if old is not None and old in self.logins and not self.logins[old].pages:
            # the browser's cookie now names the new login: nobody can use the old one
            await self._end_login(old, self.logins[old], "replaced by a new login from the "
                                                         "same browser")
        token = secrets.token_urlsafe(32)
        self._logins_made += 1
        self.logins[token] = Login(user, address, self.clock(), number=self._logins_made)
        log.info("web: %s logged in from %s (login %d)", user, address, self._logins_made)
        resp = web.json_response({"ok": True, "user": user})
        resp.set_cookie(COOKIE, token, httponly=True, secure=self.tls, samesite="Strict",
                        path="/")
        return resp

    async def _logout(self, request: web.Request) -> web.StreamResponse:
        await self._json_post(request)
        token = request.cookies.get(COOKIE)
        login = self.logins.get(token) if token else None
        if login is not None and token is not None:
            await self._end_login(token, login, "logged out")
        resp = web.json_response({"ok": True})
        resp.del_cookie(COOKIE, path="/")
        return resp

    async def _end_login(self, token: str, login: Login, why: str) -> None:
        """A login ends: its pages' console sessions end (what they held is released by
        the console, docs/console.md) and its pages are told."""
        if self.logins.pop(token, None) is None:
            return  # ended already (logged out meanwhile): said once
        log.info("web: %s's login %d from %s ended (%s)", login.user, login.number,
                 login.address, why)
        for page in list(login.pages):
            page.login = None
            await self._close_console(page)
            self._send(page, json.dumps({"t": "logout", "why": why}), keep=True)
        login.pages.clear()

    # -- pages -------------------------------------------------------------------------
    async def _ws(self, request: web.Request) -> web.StreamResponse:
        if not self._origin_ok(request):
            log.warning("web: a WebSocket from origin %r refused (this server is %s://%s)",
                        request.headers.get("Origin", "")[:80],
                        "https" if self.tls else "http", request.host)
            raise web.HTTPForbidden(text="cross-origin WebSocket refused")
        if not self._may_read(request):
            raise web.HTTPUnauthorized(text="log in to see this plant")
        if len(self.pages) >= self.conf.max_pages:
            self.refused += 1
            raise web.HTTPServiceUnavailable(text=f"{self.conf.max_pages} pages are open "
                                                  "(web: max_pages): try again later")
        page_timeout_s = self.conf.page_timeout_ns / 1e9
        ws = web.WebSocketResponse(max_msg_size=MAX_BODY,
                                   heartbeat=page_timeout_s * PING_AFTER)
        await ws.prepare(request)
        page = Page(ws, request.remote or "?", self._login_of(request), request.transport)
        if page.login is not None:
            page.login.pages.add(page)
        self.pages.add(page)
        self._update_why()
        sender = asyncio.create_task(self._sender(page))
        self._hello(page)
        try:
            async for msg in ws:
                if msg.type is not WSMsgType.TEXT:
                    break
                await self._on_message(page, msg.data)
        finally:
            if isinstance(ws.exception(), TimeoutError):  # no answer to the ping
                log.warning("web: the page of %s did not answer for %g s (web: "
                            "page_timeout): closed", page.address, page_timeout_s)
            sender.cancel()
            self.pages.discard(page)
            if page.login is not None:
                page.login.pages.discard(page)
            await self._close_console(page)
            self._update_why()
        return ws

    def _hello(self, page: Page) -> None:
        st = self.feed.state
        self._send(page, json.dumps({"t": "hello", "connected": self.feed.connected,
                                     "user": page.login.user if page.login else None}),
                   keep=True)
        if self.feed.connected and st.values:
            if st.status_current:  # none yet on this connection: the page gets none
                self._send(page, json.dumps({"t": "s", "status": st.status}))
            self._send(page, json.dumps({"t": "w", "whys": st.whys}))
            self._send(page, json.dumps({"t": "f", "scan": st.scan, "wall": st.wall,
                                         "names": st.names, "values": st.values}))
            page.fresh = False

    def _send(self, page: Page, text: str, keep: bool = False) -> None:
        """Queue ``text`` for ``page``. A page whose queue is full (it reads too slowly)
        loses the frames waiting for it and gets a whole one next; what is ``keep``
        (an action's reply, the console's notices, a new schema, the feed lost, the
        login ended: nothing a later frame says again) is kept, PAGE_QUEUE // 2 at
        most."""
        try:
            page.queue.put_nowait((keep, text))
        except asyncio.QueueFull:
            kept = []
            while not page.queue.empty():
                item = page.queue.get_nowait()
                if item[0]:
                    kept.append(item)
            for item in kept[-(PAGE_QUEUE // 2):]:
                page.queue.put_nowait(item)
            page.fresh = True
            page.resyncs += 1
            if keep:
                page.queue.put_nowait((keep, text))

    async def _sender(self, page: Page) -> None:
        try:
            while True:
                _keep, text = await page.queue.get()
                await within(page.ws.send_str(text), SEND_TIMEOUT_S)
        except TimeoutError:
            # a close frame would wait behind what it does not read: the connection ends
            log.warning("web: the page of %s did not read for %g s: closed", page.address,
                        SEND_TIMEOUT_S)
            if page.transport is not None:
                page.transport.abort()
            return
        except (ConnectionError, RuntimeError):
            pass
        await page.ws.close()

    async def _on_message(self, page: Page, data: str) -> None:
        try:
            ident, action, args = action_of(loads(data))
        except ValueError:
            self._send(page, json.dumps({"t": "r", "id": None, "ok": False,
                                         "text": "malformed message"}), keep=True)
            return
        ok, text = await self._act(page, action, args)
        self._send(page, json.dumps({"t": "r", "id": ident, "ok": ok, "text": text}),
                   keep=True)

    async def _act(self, page: Page, action: str, args: list[str]) -> tuple[bool, str]:
        login = page.login
        if login is None or login not in self.logins.values():
            return False, "log in to act"
        if action not in ACTIONS or len(args) != ACTIONS[action]:
            return False, f"unknown action {action[:20]!r}"
        if action in ("force", "unforce", "set") and args[0] not in self.feed.state.index:
            return False, f"unknown name {args[0][:64]!r}"
        if action in ("force", "set", "cycle") and not VALUE_RE.match(args[-1]):
            return False, f"not a value: {args[-1][:32]!r}"
        if self.console_path is None:
            return False, "the plant has no console socket"
        login.last = self.clock()
        try:
            if page.console is None:
                page.console = await ConsoleLink.open(
                    self.console_path, login.user, page.address,
                    lambda text: self._send(page, json.dumps({"t": "n", "text": text}),
                                            keep=True),
                    lambda why: self._console_ended(page, why))
            reply = await page.console.call(" ".join([action, *args]))
        except ConsoleUnavailable as exc:
            page.console = None
            return False, str(exc)
        if reply.get("ok"):
            return True, "; ".join(reply.get("text", [])) or "ok"
        return False, str(reply.get("error", "refused"))

    def _console_ended(self, page: Page, why: str) -> None:
        page.console = None
        self._send(page, json.dumps({"t": "n", "text": why}), keep=True)

    async def _close_console(self, page: Page) -> None:
        if page.console is not None:
            link, page.console = page.console, None
            await link.close()

    def _update_why(self) -> None:
        names = list(self.pdef.instances)[:WHY_MAX] if self.pages else []
        self.feed.follow_why(names)

    # -- the feed ----------------------------------------------------------------------
    async def _on_schema(self, schema: dict[str, Any]) -> None:
        self._last_values = []
        self._last_status, self._last_whys = None, {}
        for page in self.pages:
            page.fresh = True
            self._send(page, json.dumps({"t": "schema"}), keep=True)

    async def _on_lost(self) -> None:
        self._last_values = []
        for page in self.pages:
            page.fresh = True
            self._send(page, json.dumps({"t": "lost"}), keep=True)

    async def _on_frame(self) -> None:
        st = self.feed.state
        self.frames += 1
        # no status yet on this connection (frames from the shared image can come
        # first): the pages are sent none, not an empty one nor the last connection's
        current = st.status_current
        status = None if not current or st.status == self._last_status else json.dumps(
            {"t": "s", "status": st.status})
        if current:
            self._last_status = dict(st.status)
        changed = {k: v for k, v in st.whys.items() if self._last_whys.get(k) != v}
        whys = json.dumps({"t": "w", "whys": changed}) if changed else None
        self._last_whys = dict(st.whys)
        last, values = self._last_values, st.values
        delta = None
        if len(last) == len(values):
            changes: list[Any] = []
            for i, v in enumerate(values):
                if last[i] != v:
                    changes += (i, v)
            delta = json.dumps({"t": "d", "scan": st.scan, "wall": st.wall,
                                "changes": changes})
        self._last_values = list(values)
        whole = None
        for page in self.pages:
            if page.fresh or delta is None:
                if whole is None:
                    whole = json.dumps({"t": "f", "scan": st.scan, "wall": st.wall,
                                        "names": st.names, "values": values})
                if current:
                    self._send(page, json.dumps({"t": "s", "status": st.status}))
                self._send(page, json.dumps({"t": "w", "whys": st.whys}))
                self._send(page, whole)
                page.fresh = False
                continue
            if status is not None:
                self._send(page, status)
            if whys is not None:
                self._send(page, whys)
            self._send(page, delta)

    # -- idle logins -------------------------------------------------------------------
    async def _watch_logins(self) -> None:
        idle_s = self.conf.idle_logout_ns / 1e9
        while True:
            await asyncio.sleep(IDLE_CHECK_S)
            now = self.clock()
            for token, login in list(self.logins.items()):
                if now - login.last >= idle_s:
                    await self._end_login(token, login, f"no action for {idle_s:.0f} s "
                                                        "(web: idle_logout)")

    async def run(self, stop: asyncio.Event, ready: Callable[[WebView, int], None]
                  | None = None) -> None:
        """Serve until ``stop`` is set. ``ready(view, port)`` once listening."""
        ctx = None
        if self.tls:
            ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
            assert self.conf.certificate is not None and self.conf.private_key is not None
            ctx.load_cert_chain(self.conf.certificate, self.conf.private_key)
        # keepalive_timeout: aiohttp's timer runs from a connection's start and from each
        # response's end until the next request's headers are in: the header timeout;
        # lingering_time: how long the rest of a body not read is waited for
        runner = web.AppRunner(self.app(), access_log=None, shutdown_timeout=2.0,
                               keepalive_timeout=HEADER_TIMEOUT_S,
                               lingering_time=HEADER_TIMEOUT_S)
        await runner.setup()
        assert runner.server is not None
        self.listener = Listener(runner.server, ctx)
        # the bound one when the plant says 0 (tests)
        port = await self.listener.start(self.conf.host, self.conf.port)
        log.info("web: the page of %s is at %s://%s:%d/", self.pdef.path,
                 "https" if self.tls else "http", self.conf.host, port)
        idle = asyncio.create_task(self._watch_logins())
        if ready is not None:
            ready(self, port)
        try:
            await self.feed.run_beside(stop.wait())  # a feed refused ends it
        finally:
            idle.cancel()
            for token, login in list(self.logins.items()):
                await self._end_login(token, login, "the web view stops")
            for page in list(self.pages):
                await self._close_console(page)
            self.listener.close()
            await runner.cleanup()


async def serve(pdef: PlantDef, feed: str | None = None, stop: asyncio.Event | None = None,
                ready: Callable[[WebView, int], None] | None = None,
                coverage: list[ChartCoverage] | None = None) -> None:
    """Run the web view of ``pdef`` until ``stop`` is set (or forever)."""
    await WebView(pdef, feed, coverage=coverage).run(stop or asyncio.Event(), ready)
