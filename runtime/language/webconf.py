"""The ``web:`` section of a plant file (docs/web.md): where ``softplc web`` listens, its
certificate, who may log in and who may look. Checked against the plant: acting from the
page goes through the console, so a plant with ``users`` needs a console socket."""

from __future__ import annotations

import ipaddress
import re
from typing import Any

from runtime.errors import Loc, SourceError
from runtime.language.feedconf import FEED_KEY, feed_key, sample_key
from runtime.language.model import PlantDef, WebDef
from runtime.language.shape import (
    Choice,
    Int,
    Key,
    ListOf,
    MapOf,
    Section,
    Text,
    Time,
    expect_type,
    time_value,
)
from runtime.language.tlsconf import SERVER_TLS, pem_files
from runtime.language.yamlsrc import YMap

#: the snapshot period when the plant does not say (never below the cycle), ns
DEFAULT_SAMPLE_NS = 100_000_000
_LISTEN = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")
#: what a user name may be (it goes into log lines and console commands)
USER_RE = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")
#: a host name of ``hosts`` (a ``*.`` name stands for any one label before the rest)
HOST_RE = re.compile(r"^(\*\.)?[A-Za-z0-9_-]{1,63}(\.[A-Za-z0-9_-]{1,63})*\.?$")
#: a host of ``hosts`` as editors check it: a name (``HOST_RE``) or an address (the
#: loader's check of an address is ``ipaddress``'s)
_HOST = Text(r"^((\*\.)?[A-Za-z0-9_-]{1,63}(\.[A-Za-z0-9_-]{1,63})*\.?|\[?[0-9A-Fa-f:.]+\]?)$")
#: who may look at the page
READ = ("anyone", "users")

# -- the shape of ``web:`` (runtime/language/shape.py)
TLS = Section(SERVER_TLS, "web tls", "HTTPS: the server's certificate and key (PEM).")
WEB = Section((
    Key("listen", Text(_LISTEN.pattern), "HOST:PORT (default 127.0.0.1:8080); any address but "
                                         "a loopback one needs tls."),
    Key("sample", Time(), "How often the page is updated (the feed's sample; default 100ms, "
                          "never below the cycle)."),
    FEED_KEY,
    Key("tls", TLS),
    Key("users", MapOf(Text(), names=USER_RE.pattern),
        "user: password hash made by softplc hash-pin: who may act from the page (through "
        "the plant's console socket)."),
    Key("read", Choice(READ), "Who may look: anyone who reaches the address (default) or only "
                              "users logged in."),
    Key("idle_logout", Time(60_000_000_000, 86_400_000_000_000),
        "A login ends after this long without an action (default 10m, 1m to 24h); what its "
        "pages held is released as a console session's."),
    Key("max_pages", Int(1, 200), "Pages open at once (default 20)."),
    Key("page_timeout", Time(3_000_000_000, 600_000_000_000),
        "A page that answers nothing, not even the server's ping, for this long is closed and "
        "what it held released: a browser frozen or a laptop asleep while it holds a force "
        "halts the controller after this long (default 30s, 3s to 10m)."),
    Key("hosts", ListOf(_HOST), "Names the page is reached by besides its listen address, "
                                "localhost, 127.0.0.1, ::1 and its certificate's names (a *. "
                                "name matches one label): a request naming another host is "
                                "refused (DNS rebinding)."),
), "web", "The live view in the browser, `softplc web PLANT` (docs/web.md): where it listens, "
          "HTTPS, who may act and who may look.", null=True)


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address, or ``localhost``) is this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def listen_value(text: str, tls: bool, loc: Loc) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); port 0 takes a free port (tests). Without ``tls``,
    only a loopback address. SourceError at ``loc``."""
    match = _LISTEN.match(text)
    if match is None or not 0 <= int(match.group(2)) < 65536:
        raise SourceError(loc, f"web listen: expected HOST:PORT (e.g. 127.0.0.1:8080, "
                               f"0.0.0.0:8443), found '{text}'")
    host = match.group(1).strip("[]")
    if not tls and not is_loopback(host):
        raise SourceError(loc, f"web listen: {host} is reachable from other machines: serve "
                               "it over HTTPS (web: tls: {certificate: ..., private_key: "
                               "...}, docs/web.md), or listen on 127.0.0.1")
    return host, int(match.group(2))


def load_web(p: PlantDef, value: Any, loc: Loc) -> WebDef:
    """``web:`` -> WebDef; SourceError at the faulty key or value. An empty ``web:`` (``web:
    {}``) serves the page read-only on 127.0.0.1:8080."""
    m = expect_type(value, loc, YMap, "a mapping (listen, sample, tls, users, read, ...)")
    WEB.check(m)
    w = WebDef(loc=loc, sample_ns=max(DEFAULT_SAMPLE_NS, p.cycle_ns), locs=dict(m.val_locs))
    if "listen" in m:
        vloc = m.val_locs["listen"]
        w.host, w.port = listen_value(expect_type(m["listen"], vloc, str, "HOST:PORT"),
                                      True, vloc)
    if "sample" in m:
        w.sample_ns = sample_key(p, m, "web")
    if "feed" in m:  # the default: runtime/language/feedconf.py, once every section is read
        w.feed = feed_key(m, "web")
    if "tls" in m:
        vloc = m.val_locs["tls"]
        tls = expect_type(m["tls"], vloc, YMap, "a mapping (certificate, private_key)")
        TLS.check(tls)
        files = pem_files(p.path, tls, TLS.names, "web tls", vloc, w.tls_locs)
        w.certificate, w.private_key = files["certificate"], files["private_key"]
    if "listen" in m:
        listen_value(str(m["listen"]), w.certificate is not None, m.val_locs["listen"])
    if "users" in m:
        vloc = m.val_locs["users"]
        users = expect_type(m["users"], vloc, YMap, "a mapping user: password hash")
        for user, h in users.items():
            uloc = users.val_locs[user]
            if not USER_RE.match(str(user)):
                raise SourceError(uloc, f"web users: '{user}': expected a name of letters, "
                                        "digits, '_', '.', '-' (at most 32)")
            if not isinstance(h, str) or "$" not in h:
                raise SourceError(uloc, f"web users: {user}: expected a password hash made "
                                        "by 'softplc hash-pin'")
            w.users[str(user)] = h
        if w.users and not any(c.kind == "socket" for c in p.consoles):
            raise SourceError(vloc, "web users: acting from the page goes through the "
                                    "controller's console socket, and the plant has none: "
                                    "add monitor: socket: {path: '${RUNTIME_DIR}/console.sock'}")
    if "read" in m:
        vloc = m.val_locs["read"]
        if m["read"] not in READ:
            raise SourceError(vloc, f"web read: expected anyone or users, found "
                                    f"'{m['read']}'")
        w.read = str(m["read"])
        if w.read == "users" and not w.users:
            raise SourceError(vloc, "web read: users: nobody could look: add web: users")
    if "idle_logout" in m:
        vloc = m.val_locs["idle_logout"]
        w.idle_logout_ns = time_value(m["idle_logout"], vloc, "web idle_logout")
        if not WEB["idle_logout"].low <= w.idle_logout_ns <= WEB["idle_logout"].high:
            raise SourceError(vloc, "web idle_logout: expected 1m to 24h")
    if "max_pages" in m:
        vloc = m.val_locs["max_pages"]
        n = WEB.value(m, "max_pages", "a number of pages")
        low, high = WEB["max_pages"].low, WEB["max_pages"].high
        if not low <= n <= high:
            raise SourceError(vloc, f"web max_pages: expected {low} to {high}, found {n}")
        w.max_pages = int(n)
    if "page_timeout" in m:
        vloc = m.val_locs["page_timeout"]
        w.page_timeout_ns = time_value(m["page_timeout"], vloc, "web page_timeout")
        if not WEB["page_timeout"].low <= w.page_timeout_ns <= WEB["page_timeout"].high:
            raise SourceError(vloc, "web page_timeout: expected 3s to 10m")
    if "hosts" in m:
        vloc = m.val_locs["hosts"]
        hosts = WEB.value(m, "hosts", "a list of host names")
        for h, hloc in zip(hosts, hosts.locs, strict=True):
            if not isinstance(h, str) or not (HOST_RE.match(h) or _is_address(h)):
                raise SourceError(hloc, f"web hosts: expected a host name or address "
                                        f"(e.g. plc.bench.lan, *.bench.lan, 192.168.1.20), "
                                        f"found '{h}'")
            w.hosts.append(h)
    return w


def _is_address(text: str) -> bool:
    try:
        ipaddress.ip_address(text.strip("[]"))
    except ValueError:
        return False
    return True
