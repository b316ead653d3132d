"""The ``web:`` section of a plant file (docs/web.md): where ``softplc web`` listens, its
certificate, who may log in and who may look. Checked against the plant: acting from the
page goes through the console, so a plant with ``users`` needs a console socket."""

from __future__ import annotations

import ipaddress
import re
from typing import Any

from runtime.errors import Loc, SourceError
from runtime.language.feedconf import feed_key, sample_key
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.model import PlantDef, WebDef
from runtime.language.plantpaths import path_value
from runtime.language.yamlsrc import YList, YMap

WEB_KEYS = ("listen", "sample", "feed", "tls", "users", "read", "idle_logout", "max_pages",
            "page_timeout", "hosts")
TLS_KEYS = ("certificate", "private_key")
#: the snapshot period when the plant does not say (never below the cycle), ns
DEFAULT_SAMPLE_NS = 100_000_000
#: pages (WebSocket connections) at most, whatever the plant says
MAX_PAGES_LIMIT = 200
_LISTEN = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})$")
#: what a user name may be (it goes into log lines and console commands)
USER_RE = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")
#: a host name of ``hosts`` (a ``*.`` name stands for any one label before the rest)
HOST_RE = re.compile(r"^(\*\.)?[A-Za-z0-9_-]{1,63}(\.[A-Za-z0-9_-]{1,63})*\.?$")
#: the bounds of ``page_timeout``, ns (3 s: a ping every 2 s, 1 s for its answer)
PAGE_TIMEOUT_MIN_NS = 3_000_000_000
PAGE_TIMEOUT_MAX_NS = 600_000_000_000


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
    check_keys(m, WEB_KEYS, "web")
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
        check_keys(tls, TLS_KEYS, "web tls")
        for key in TLS_KEYS:
            if key not in tls:
                raise SourceError(vloc, f"web tls: expected {key} (a PEM file), found none")
            setattr(w, key, path_value(tls[key], tls.val_locs[key], f"web tls {key}"))
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
        if m["read"] not in ("anyone", "users"):
            raise SourceError(vloc, f"web read: expected anyone or users, found "
                                    f"'{m['read']}'")
        w.read = str(m["read"])
        if w.read == "users" and not w.users:
            raise SourceError(vloc, "web read: users: nobody could look: add web: users")
    if "idle_logout" in m:
        vloc = m.val_locs["idle_logout"]
        w.idle_logout_ns = time_value(m["idle_logout"], vloc, "web idle_logout")
        if not 60_000_000_000 <= w.idle_logout_ns <= 86_400_000_000_000:
            raise SourceError(vloc, "web idle_logout: expected 1m to 24h")
    if "max_pages" in m:
        vloc = m.val_locs["max_pages"]
        n = expect_type(m["max_pages"], vloc, int, "a number of pages")
        if not 1 <= n <= MAX_PAGES_LIMIT:
            raise SourceError(vloc, f"web max_pages: expected 1 to {MAX_PAGES_LIMIT}, "
                                    f"found {n}")
        w.max_pages = int(n)
    if "page_timeout" in m:
        vloc = m.val_locs["page_timeout"]
        w.page_timeout_ns = time_value(m["page_timeout"], vloc, "web page_timeout")
        if not PAGE_TIMEOUT_MIN_NS <= w.page_timeout_ns <= PAGE_TIMEOUT_MAX_NS:
            raise SourceError(vloc, "web page_timeout: expected 3s to 10m")
    if "hosts" in m:
        vloc = m.val_locs["hosts"]
        hosts = expect_type(m["hosts"], vloc, YList, "a list of host names")
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
