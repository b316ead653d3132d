"""The ``opcua:`` section of a plant file (docs/opcua.md): endpoint, feed, writable names,
security. Checked against the plant: a writable name must be a variable or chart flag an
OPC UA client may set between two scans."""

from __future__ import annotations

import re
from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.grafcetfile import check_keys, expect_type, time_value
from runtime.language.model import OPCUA_POLICIES, OpcuaDef, OpcuaSecurity, PlantDef, VarKind
from runtime.language.plantpaths import path_problem, path_value
from runtime.language.runtimedir import default_feed
from runtime.language.yamlsrc import YMap

OPCUA_KEYS = ("endpoint", "sample", "feed", "writable", "security")
SECURITY_KEYS = ("policies", "certificate", "private_key", "trusted_clients",
                 "trusted_readers", "anonymous", "users")
#: the snapshot period when the plant does not say (never below the cycle), ns
DEFAULT_SAMPLE_NS = 50_000_000
_ENDPOINT = re.compile(r"^opc\.tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d{1,5})(/.*)?$")


def load_opcua(p: PlantDef, value: Any, loc: Loc) -> OpcuaDef:
    """``opcua:`` -> OpcuaDef; SourceError at the faulty key or value."""
    m = expect_type(value, loc, YMap, "a mapping (endpoint, sample, feed, writable, "
                                      "security)")
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
        vloc = m.val_locs["sample"]
        o.sample_ns = time_value(m["sample"], vloc, "opcua sample")
        if o.sample_ns < p.cycle_ns:
            raise SourceError(vloc, f"opcua sample must be at least the cycle "
                                    f"({p.cycle_ns / 1e6:g} ms): a snapshot is taken at the "
                                    "end of a scan")
    if "feed" in m:
        o.feed = path_value(m["feed"], m.val_locs["feed"], "opcua feed", socket=True)
    else:
        o.feed = default_feed([c.address for c in p.consoles if c.kind == "socket"], loc)
        problem = path_problem(o.feed, socket=True)
        if problem is not None:
            raise SourceError(loc, f"opcua feed (by default {o.feed}): {problem}: give "
                                   "'feed:' a shorter path")
    if "writable" in m:
        o.writable = _writable(p, m["writable"], m.val_locs["writable"])
    if "security" in m:
        o.security = _security(m["security"], m.val_locs["security"])
    return o


def _writable(p: PlantDef, value: Any, loc: Loc) -> list[str]:
    items = expect_type(value, loc, list, "a list of instance.name")
    locs = getattr(items, "locs", None)
    out: list[str] = []
    for k, item in enumerate(items):
        iloc = locs[k] if locs is not None and k < len(locs) else loc
        name = str(expect_type(item, iloc, str, "instance.name"))
        problem = writable_problem(p, name)
        if problem is not None:
            raise SourceError(iloc, f"opcua writable: {problem}")
        if name not in out:
            out.append(name)
    return out


def writable_problem(p: PlantDef, name: str) -> str | None:
    """Why ``name`` cannot be written by OPC UA clients, or None if it can: only memory
    variables and chart flags that nothing else writes every scan."""
    head, _, rest = name.partition(".")
    if head in p.drivers:
        return (f"'{name}' is a driver point: physical points are never written over OPC UA "
                "(bind a memory variable, or force it from the console)")
    idef = p.instances.get(head)
    if idef is None or not rest:
        return (f"unknown instance in '{name}': expected instance.variable"
                f"{suggest(head, p.instances)}")
    g = idef.grafcet
    var = g.variables.get(rest)
    if var is None:
        names = [v.name for v in g.variables.values()
                 if v.kind in (VarKind.MEMORY, VarKind.FLAG)]
        return f"'{name}': {head} has no variable '{rest}'{suggest(rest, names)}"
    if var.kind is VarKind.FLAG:
        if var.type is not A.Type.BOOL:
            return f"'{name}' is a {var.type.value} chart flag, read-only"
        b = idef.inputs.get(rest)
        if b is not None:
            return f"'{name}' is bound to {b.source}, which sets it before every scan"
        return None
    if var.kind is VarKind.MEMORY:
        return None
    why = {VarKind.INPUT: "an input, copied from its binding before every scan",
           VarKind.OUTPUT: "an output, written by the chart every scan",
           VarKind.TEMP: "a temporary, assigned by the chart every scan",
           VarKind.SYSTEM: "a system value"}[var.kind]
    return f"'{name}' is {why}: expected a memory variable or a chart flag"


def _security(value: Any, loc: Loc) -> OpcuaSecurity:
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
            vloc = m.val_locs[key]
            setattr(sec, key, path_value(m[key], vloc, f"opcua security {key}"))
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
