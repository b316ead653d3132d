"""The feed in a plant file: its socket, and what the side processes (``opcua:``, ``mqtt:``)
may write through it.

The socket is one per plant, whichever sections name it. A section's ``feed:`` key is
optional; when none names it, the feed is ``${RUNTIME_DIR}/feed.sock``, in the plant's own
runtime directory (runtime/language/runtimedir.py): never another plant's.

A section's ``writable:`` names are memory variables and Boolean chart flags that nothing
else writes every scan: what a client may set between two scans (``writable_problem``)."""

from __future__ import annotations

from typing import Any

from runtime.errors import Loc, SourceError, suggest
from runtime.language import ast as A
from runtime.language.grafcetfile import expect_type, time_value
from runtime.language.model import PlantDef, VarKind
from runtime.language.plantpaths import path_problem, path_value
from runtime.language.runtimedir import default_feed
from runtime.language.yamlsrc import YMap


def sample_key(p: PlantDef, m: YMap, section: str) -> int:
    """A section's ``sample:`` (ns): a snapshot period, never below the cycle."""
    vloc = m.val_locs["sample"]
    ns = time_value(m["sample"], vloc, f"{section} sample")
    if ns < p.cycle_ns:
        raise SourceError(vloc, f"{section} sample must be at least the cycle "
                                f"({p.cycle_ns / 1e6:g} ms): a snapshot is taken at the end "
                                "of a scan")
    return ns


def feed_key(m: YMap, section: str) -> str:
    """A section's ``feed:``, a Unix socket's path (the default comes with
    ``settle_feed``)."""
    return path_value(m["feed"], m.val_locs["feed"], f"{section} feed", socket=True)


def settle_feed(p: PlantDef, named: dict[str, Loc]) -> None:
    """Give every side process section of ``p`` the plant's one feed path. ``named``:
    section -> the place of its ``feed:`` value, for the sections that have the key (their
    ``feed`` holds the expanded path); two sections naming two paths is an error."""
    sections = [(k, s) for k, s in p.side_sections() if s is not None]
    if not sections:
        return
    path = ""
    first = ""
    for key, section in sections:
        if key not in named:
            continue
        if path and section.feed != path:
            raise SourceError(named[key], f"{key} feed: a plant has one feed, and {first} "
                                          f"feed names {path}: name the same socket or "
                                          "leave one out")
        path, first = section.feed, key
    if not path:
        loc = sections[0][1].loc or Loc(p.path, 1, 1)
        path = default_feed(Loc(p.path, 1, 1))
        problem = path_problem(path, socket=True)
        if problem is not None:
            raise SourceError(loc, f"{sections[0][0]} feed (by default {path}): {problem}: "
                                   "give 'feed:' a shorter path")
    for key, section in sections:
        section.feed = path
        section.feed_loc = named.get(key, section.loc)


#: how a section's side process is named in messages
SIDE_NAMES = {"opcua": "OPC UA", "mqtt": "MQTT", "web": "the web view"}


def writable_names(p: PlantDef, value: Any, loc: Loc, section: str) -> list[str]:
    """``SECTION: writable:`` -> its names, once each; SourceError at the first that may
    not be written."""
    items = expect_type(value, loc, list, "a list of instance.name")
    locs = getattr(items, "locs", None)
    out: list[str] = []
    for k, item in enumerate(items):
        iloc = locs[k] if locs is not None and k < len(locs) else loc
        name = str(expect_type(item, iloc, str, "instance.name"))
        problem = writable_problem(p, name, SIDE_NAMES[section])
        if problem is not None:
            raise SourceError(iloc, f"{section} writable: {problem}")
        if name not in out:
            out.append(name)
    return out


def writable_problem(p: PlantDef, name: str, side: str = "OPC UA") -> str | None:
    """Why ``name`` cannot be written by ``side``'s clients, or None if it can: only
    memory variables and chart flags that nothing else writes every scan."""
    head, _, rest = name.partition(".")
    if head in p.drivers:
        return (f"'{name}' is a driver point: physical points are never written over {side} "
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
