"""The ``opcua:`` section of a plant file (docs/opcua.md): endpoint, feed, writable names, limits,
security. Checked against the plant: a writable name must be a variable or chart flag an
OPC UA client may set between two scans. The certificate, key and trusted directories are
read from the plant file's directory when relative (as every path of a plant file:
``plantpaths.resolve``) and must be there when the OPC UA server starts
(``security_problems``: ``softplc check`` and ``softplc opcua`` refuse a missing one at its
value, and making a new pair is advised only when neither file of it is there; the
controller itself loads the plant without them)."""

from __future__ import annotations

import re
from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language.feedconf import feed_key, sample_key, writable_names
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.model import OPCUA_POLICIES, OpcuaDef, OpcuaLimits, OpcuaSecurity, PlantDef
from runtime.language.plantpaths import missing, plant_path
from runtime.language.yamlsrc import YMap

OPCUA_KEYS = ("endpoint", "sample", "feed", "writable", "security", "limits")
#: ``limits:`` counts: key -> (attribute, least, greatest)
LIMIT_COUNTS = {"sessions": ("sessions", 1, 1000),
                "subscriptions": ("subscriptions", 1, 100),
                "items": ("items", 1, 1_000_000),
                "items_total": ("items_total", 1, 10_000_000)}
#: ``limits:`` rates (publishes a second): key -> (attribute, least, greatest)
LIMIT_RATES = {"publish_rate": ("publish_rate", 0.1, 10_000.0),
               "publish_rate_total": ("publish_rate_total", 0.1, 100_000.0)}
#: ``limits:`` times: key -> (attribute, least, greatest), ns
LIMIT_TIMES = {"session_timeout": ("session_timeout_ns", 10_000_000_000, 3_600_000_000_000),
               "abandoned": ("abandoned_ns", 1_000_000_000, 3_600_000_000_000)}
SECURITY_KEYS = ("policies", "certificate", "private_key", "trusted_clients",
                 "trusted_readers", "anonymous", "users")
#: the snapshot period when the plant does not say (never below the cycle), ns
DEFAULT_SAMPLE_NS = 50_000_000
_ENDPOINT = re.compile(r"^opc\.tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})(/.*)?$")


def load_opcua(p: PlantDef, value: Any, loc: Loc) -> OpcuaDef:
    """``opcua:`` -> OpcuaDef; SourceError at the faulty key or value."""
    m = expect_type(value, loc, YMap, "a mapping (endpoint, sample, feed, writable, "
                                      "security, limits)")
    check_keys(m, OPCUA_KEYS, "opcua")
    o = OpcuaDef(loc=loc, sample_ns=max(DEFAULT_SAMPLE_NS, p.cycle_ns),
                 locs=dict(m.val_locs))
    if "endpoint" in m:
        vloc = m.val_locs["endpoint"]
        ep = str(expect_type(m["endpoint"], vloc, str, "opc.tcp://HOST:PORT"))
        match = _ENDPOINT.match(ep)
        if match is None or not 0 < int(match.group(2)) < 65536:
            raise SourceError(vloc, f"opcua endpoint: expected opc.tcp://HOST:PORT (e.g. "
                                    f"opc.tcp://127.0.0.1:4840), found '{ep}'")
        o.endpoint = ep
    if "sample" in m:
        o.sample_ns = sample_key(p, m, "opcua")
    if "feed" in m:  # the default: runtime/language/feedconf.py, once every section is read
        o.feed = feed_key(m, "opcua")
    if "writable" in m:
        o.writable = writable_names(p, m["writable"], m.val_locs["writable"], "opcua")
    if "security" in m:
        o.security = _security(m["security"], m.val_locs["security"], p.path)
    if "limits" in m:
        o.limits = _limits(m["limits"], m.val_locs["limits"])
    return o


def _limits(value: Any, loc: Loc) -> OpcuaLimits:
    keys = (*LIMIT_COUNTS, *LIMIT_RATES, *LIMIT_TIMES)
    m = expect_type(value, loc, YMap, f"a mapping ({', '.join(keys)})")
    check_keys(m, keys, "opcua limits")
    lim = OpcuaLimits(loc=loc)
    for key, (attr, least, most) in LIMIT_COUNTS.items():
        if key in m:
            vloc = m.val_locs[key]
            n = expect_type(m[key], vloc, int, "a whole number")
            if not least <= n <= most:
                raise SourceError(vloc, f"opcua limits {key}: expected {least} to {most}, "
                                        f"found {n}")
            setattr(lim, attr, n)
    for key, (attr, low, high) in LIMIT_RATES.items():
        if key in m:
            vloc = m.val_locs[key]
            rate = expect_type(m[key], vloc, (int, float), "publishes a second (a number)")
            if not low <= rate <= high:
                raise SourceError(vloc, f"opcua limits {key}: expected {low:g} to {high:g} "
                                        f"publishes a second, found {rate:g}")
            setattr(lim, attr, float(rate))
    for key, (attr, least, most) in LIMIT_TIMES.items():
        if key in m:
            vloc = m.val_locs[key]
            ns = time_value(m[key], vloc, f"opcua limits {key}")
            if not least <= ns <= most:
                raise SourceError(vloc, f"opcua limits {key}: expected {least // 10**9} s to "
                                        f"{most // 10**9} s, found {ns / 1e9:g} s")
            setattr(lim, attr, ns)
    if lim.items > lim.items_total:
        where = m.val_locs.get("items", m.val_locs.get("items_total", loc))
        raise SourceError(where, f"opcua limits: items ({lim.items}) per session is more than "
                                 f"items_total ({lim.items_total}), the limit of all sessions")
    if lim.publish_rate > lim.publish_rate_total:
        where = m.val_locs.get("publish_rate", m.val_locs.get("publish_rate_total", loc))
        raise SourceError(where, f"opcua limits: publish_rate ({lim.publish_rate:g}) per "
                                 "session is more than publish_rate_total "
                                 f"({lim.publish_rate_total:g}), the limit of all sessions")
    if lim.abandoned_ns > lim.session_timeout_ns:
        raise SourceError(m.val_locs.get("abandoned", loc),
                          f"opcua limits abandoned ({lim.abandoned_ns / 1e9:g} s) is longer "
                          f"than session_timeout ({lim.session_timeout_ns / 1e9:g} s)")
    return lim


def _security(value: Any, loc: Loc, base: str) -> OpcuaSecurity:
    m = expect_type(value, loc, YMap, "a mapping (policies, certificate, ...)")
    check_keys(m, SECURITY_KEYS, "opcua security")
    sec = OpcuaSecurity(loc=loc)
    if "policies" in m:
        vloc = m.val_locs["policies"]
        pol = expect_type(m["policies"], vloc, list, f"a list of {', '.join(OPCUA_POLICIES)}")
        if not pol:
            raise SourceError(vloc, "opcua security policies: expected at least one of "
                                    f"{', '.join(OPCUA_POLICIES)}")
        sec.policies = []
        plocs = getattr(pol, "locs", None)
        for k, item in enumerate(pol):
            text = "None" if item is None else str(item)
            if text not in OPCUA_POLICIES:
                raise SourceError(plocs[k] if plocs else vloc,
                                  f"opcua security policies: unknown policy '{text}': "
                                  f"expected one of {', '.join(OPCUA_POLICIES)}"
                                  f"{suggest(text, OPCUA_POLICIES)}")
            if text not in sec.policies:
                sec.policies.append(text)
    for key in ("certificate", "private_key", "trusted_clients", "trusted_readers"):
        if key in m:
            vloc = sec.locs[key] = m.val_locs[key]
            setattr(sec, key, plant_path(base, m[key], vloc, f"opcua security {key}"))
    if "anonymous" in m:
        vloc = m.val_locs["anonymous"]
        if m["anonymous"] not in ("read", "none"):
            raise SourceError(vloc, f"opcua security anonymous: expected read or none, found "
                                    f"'{m['anonymous']}'")
        sec.anonymous = str(m["anonymous"])
    if "users" in m:
        vloc = m.val_locs["users"]
        users = expect_type(m["users"], vloc, YMap, "a mapping user: password hash")
        for user, h in users.items():
            if not isinstance(h, str) or "$" not in h:
                raise SourceError(users.val_locs[user], f"opcua security users: {user}: "
                                  "expected a password hash made by 'softplc hash-pin'")
            sec.users[str(user)] = h
    return sec


def security_problems(sec: OpcuaSecurity) -> list[SourceError]:
    """What of the files ``sec`` names is not there (or not of its kind), each a
    SourceError at its value: the certificate or key (``credential_problem``), a trusted
    directory. Not checked at load (``softplc run`` serves no OPC UA and must not be kept
    from running a machine by a missing certificate): ``softplc check`` reports them as
    G308 errors and ``softplc opcua`` refuses to start on the first
    (``check_security``)."""
    out: list[SourceError] = []
    problem = credential_problem(sec)
    if problem is not None:
        out.append(SourceError(sec.locs[problem[0]], f"opcua security {problem[0]}: "
                                                     f"{problem[1]}"))
    for key in ("trusted_clients", "trusted_readers"):
        path = getattr(sec, key)
        why = missing(path, directory=True) if path else None
        if why is not None:
            if why.startswith("no "):
                why += (" (the directory of the client certificates to trust: make it, "
                        "docs/opcua.md, 'Step by step')")
            out.append(SourceError(sec.locs[key], f"opcua security {key}: {why}"))
    return out


def check_security(sec: OpcuaSecurity) -> None:
    """Raise the first of ``security_problems`` (the OPC UA server's start)."""
    problems = security_problems(sec)
    if problems:
        raise problems[0]


def credential_problem(sec: OpcuaSecurity) -> tuple[str, str] | None:
    """The first of ``certificate`` and ``private_key`` named but not there (or not a
    file), and why: (key, text). A new pair (``softplc opcua-cert``) is advised only when
    neither file is there: it never overwrites one, and a certificate without its key (or
    the reverse) is a pair to restore. None when both are there (or not named)."""
    pair = {"certificate": sec.certificate, "private_key": sec.private_key}
    for key, path in pair.items():
        why = missing(path) if path else None
        if why is None:
            continue
        if why.startswith("no file"):
            other_key = "private_key" if key == "certificate" else "certificate"
            other = pair[other_key]
            if other and missing(other) is None:
                why += (f" (its {other_key.replace('_', ' ')} {other} is there: put this "
                        "file of the pair back beside it, or move that one away and make a "
                        "new pair with 'softplc opcua-cert', docs/opcua.md)")
            else:
                why += " (make one with 'softplc opcua-cert', docs/opcua.md)"
        return key, why
    return None
