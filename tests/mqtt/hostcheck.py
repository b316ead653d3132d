"""What a Sparkplug B host application checks of an edge node, over the rows the host
application (host/host.py) decoded: every birth, every sequence number, every death.

Rules (Sparkplug B 3.0, edge node side): an NBIRTH has ``seq`` 0 and a ``bdSeq`` metric;
every later NDATA, DBIRTH, DDATA, DDEATH of the session has the previous ``seq`` + 1
(modulo 256); a device's DDATA or DDEATH comes after its DBIRTH in the session; a data
metric's alias was born; an NDEATH whose ``bdSeq`` is the session's ends it (an older one,
from a session already replaced, changes nothing); nothing but an NBIRTH comes after the
death. A host reconnection (a row ``HOST_CONNECTED``) starts afresh: what it missed is no
fault of the node.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any


@dataclass
class NodeView:
    """One edge node as the host saw it."""

    bdseq: int | None = None
    seq: int | None = None
    devices: set[str | None] = field(default_factory=set)
    aliases: set[tuple[str | None, int]] = field(default_factory=set)
    births: int = 0
    device_births: int = 0
    deaths: int = 0
    device_deaths: int = 0
    data: int = 0
    historical: int = 0
    bdseqs: list[int] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def bdseq_of(row: dict[str, Any]) -> int | None:
    for m in row["metrics"]:
        if m["name"] == "bdSeq":
            return int(m["value"])
    return None


def check(rows: Iterable[dict[str, Any]]) -> dict[tuple[str, str], NodeView]:
    """Every edge node's view, with the rules broken (``problems``)."""
    nodes: dict[tuple[str, str], NodeView] = {}
    for r in rows:
        kind = r.get("kind")
        if kind == "HOST_CONNECTED":
            for v in nodes.values():  # messages may have been missed: start afresh
                v.bdseq, v.seq = None, None
                v.devices.clear()
            continue
        if kind in (None, "STATE", "NCMD", "DCMD") or "error" in r:
            if "error" in r and "CMD" not in r.get("topic", ""):
                nodes.setdefault(("?", "?"), NodeView()).problems.append(
                    f"undecodable: {r['topic']}")
            continue
        v = nodes.setdefault((r["group"], r["edge"]), NodeView())
        where = f"{kind} {r['topic']} seq {r.get('seq')}"
        if kind == "NBIRTH":
            v.births += 1
            b = bdseq_of(r)
            if r["seq"] != 0:
                v.problems.append(f"{where}: an NBIRTH's seq must be 0")
            if b is None:
                v.problems.append(f"{where}: no bdSeq")
            v.bdseq, v.seq = b, r["seq"]
            v.bdseqs.append(b if b is not None else -1)
            v.devices.clear()
            v.aliases = {(None, m["alias"]) for m in r["metrics"]}
            continue
        if kind == "NDEATH":
            b = bdseq_of(r)
            if v.bdseq is not None and b == v.bdseq:
                v.deaths += 1
                v.bdseq, v.seq = None, None
                v.devices.clear()
            continue
        if v.bdseq is None:
            if v.births:  # after a death or a host reconnection: births come first
                v.problems.append(f"{where}: before the node's birth")
            continue
        if r["seq"] != ((v.seq or 0) + 1) % 256:
            v.problems.append(f"{where}: expected seq {((v.seq or 0) + 1) % 256}")
        v.seq = r["seq"]
        dev = r.get("device")
        if kind == "DBIRTH":
            v.device_births += 1
            v.devices.add(dev)
            v.aliases |= {(dev, m["alias"]) for m in r["metrics"]}
        elif kind == "DDEATH":
            v.device_deaths += 1
            if dev not in v.devices:
                v.problems.append(f"{where}: the death of a device not born")
            v.devices.discard(dev)
        else:  # NDATA, DDATA
            v.data += 1
            if dev is not None and dev not in v.devices:
                v.problems.append(f"{where}: data of a device not born")
            for m in r["metrics"]:
                v.historical += bool(m["historical"])
                if m["alias"] is not None and (dev, m["alias"]) not in v.aliases:
                    v.problems.append(f"{where}: alias {m['alias']} never born")
    return nodes
