"""The files ``softplc import`` writes: each chart as a grafcet YAML file, and a plant
skeleton that binds every chart's inputs and outputs to simulated I/O."""

from __future__ import annotations

import json
from collections.abc import Iterable
from typing import Any

import yaml

from drivers.durations import format_ns
from runtime.language.located import parse_located
from runtime.language.yamlsrc import YList, YMap
from runtime.plcopen.program import PlantInstance


class _Flow(dict[str, Any]):
    """A mapping written on one line: ``{from: A, to: B, when: iX}``."""


class _FlowList(list[Any]):
    """A list written on one line: ``[iA, iB]``."""


#: libyaml's emitter when PyYAML has it (about 5 times as fast), else PyYAML's own
_Base: type[yaml.SafeDumper] = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


class _Dumper(_Base):  # type: ignore[misc,valid-type]
    """Block style, multi-line texts as literal blocks (``|``), short transitions and lists
    of names on one line."""


def _str(dumper: yaml.SafeDumper, text: str) -> yaml.ScalarNode:
    if "\n" in text:
        return dumper.represent_scalar("tag:yaml.org,2002:str", text.rstrip("\n") + "\n",
                                       style="|")
    return dumper.represent_scalar("tag:yaml.org,2002:str", text)


_Dumper.add_representer(str, _str)
_Dumper.add_representer(_Flow, lambda d, m: d.represent_mapping(
    "tag:yaml.org,2002:map", m.items(), flow_style=True))
_Dumper.add_representer(_FlowList, lambda d, v: d.represent_sequence(
    "tag:yaml.org,2002:seq", v, flow_style=True))


def _plain(value: Any, key: str = "") -> Any:
    """The document as plain YAML data (the loader's YStr/YMap/YList are subclasses)."""
    if isinstance(value, YMap) or isinstance(value, dict):
        out = {str(k): _plain(v, str(k)) for k, v in value.items()}
        if key == "transition" and all(_short(v) for v in out.values()):
            return _Flow(out)
        return out
    if isinstance(value, YList) or isinstance(value, list):
        items = [_plain(v, "transition" if key == "transitions" else "") for v in value]
        if key in ("inputs", "outputs", "timers", "from", "to") and all(
                _short(v) and not _nested(v) for v in items):
            return _FlowList(items)
        return items
    if isinstance(value, str):
        return str(value)
    return value


def _nested(v: Any) -> bool:
    """A mapping holding a mapping (a signal with its description): written in block
    style."""
    return isinstance(v, dict) and any(isinstance(x, dict) for x in v.values())


def _short(v: Any) -> bool:
    if isinstance(v, dict):
        return all(_short(x) for x in v.values())
    if isinstance(v, list):
        return all(_short(x) for x in v)
    return not (isinstance(v, str) and ("\n" in v or len(v) > 60))


def chart_yaml(doc: YMap, header: Iterable[str] = ()) -> str:
    """The text of a grafcet file holding ``doc`` (an imported chart's document)."""
    lines = [f"# {h}" for h in header]
    body = yaml.dump(_plain(doc), Dumper=_Dumper, sort_keys=False, allow_unicode=True,
                     default_flow_style=False, width=100)
    return "\n".join(lines) + ("\n" if lines else "") + body


#: a signal of a chart as the plant skeleton binds it: (name, type, address in the file)
Signal = tuple[str, str, str]


def plant_yaml(instances: list[tuple[PlantInstance, str, list[Signal], list[Signal]]],
               cycle_ns: int | None, header: Iterable[str] = (),
               drivers: Iterable[tuple[str, str, dict[str, Any]]] = ()) -> str:
    """A plant on simulated I/O: ``instances`` as (instance, chart file, the chart's inputs,
    its outputs). An input the instance's wiring links to another instance's output is
    bound to it; one wired to a variable of the program reads that variable's point (shared
    by its readers); the others have a point of their own. The sim driver's points are bits
    by any name and numbers on IR.../HR... (drivers/registry.py). A signal whose point and
    address softplc's export recorded is bound to them, and ``drivers`` (softplc's export's
    too) are the plant's drivers, with ``sim`` besides if a point of its own is needed."""
    out: list[str] = []
    count = {"I": 0, "Q": 0, "IR": 0, "HR": 0}
    shared: dict[tuple[str, str], str] = {}

    def point(way: str, typ: str) -> str:
        table = {"in": "I", "out": "Q"}[way] + ("" if typ == "bool" else "R")
        table = {"IR": "IR", "QR": "HR"}.get(table, table)
        p = f"sim.{table}{count[table]}"
        count[table] += 1
        return p

    for inst, chart, inputs, outputs in instances:
        out += [f"  {_q(inst.name)}:", f"    grafcet: {_q(chart)}"]
        if inst.description:
            out.append(f"    description: {json.dumps(inst.description, ensure_ascii=False)}")
        if inputs:
            out.append("    inputs:")
        for sig, typ, address in inputs:
            wire = inst.inputs.get(sig)
            note = f"{address} in the PLCopen file" if address else ""
            at = ""
            if wire is not None and wire.link:
                source = wire.link
            elif wire is not None and wire.source:
                source, at, note = wire.source, wire.at, ""
            elif wire is not None and wire.shared:
                key = (wire.shared, typ)
                if key not in shared:
                    shared[key] = point("in", typ)
                source = shared[key]
                note, at = binding_at(wire.note, wire.address, typ, "I")
            else:
                source = point("in", typ)
                note, at = binding_at(note, address, typ, "I")
            invert = wire is not None and wire.invert
            description = wire.description if wire is not None else ""
            out.append(f"      {_q(sig)}: {_binding(source, invert, description, at)}"
                       + (f"  # {_line(note)}" if note else ""))
        if outputs:
            out.append("    outputs:")
        for sig, typ, address in outputs:
            note = inst.outputs.get(sig) or (f"{address} in the PLCopen file" if address
                                             else "")
            if sig in inst.sources:
                (source, at), note = inst.sources[sig], ""
            else:
                source = point("out", typ)
                note, at = binding_at(note, inst.addresses.get(sig, address) if sig in
                                    inst.outputs else address, typ, "Q")
            out.append(f"      {_q(sig)}: "
                       f"{_binding(source, False, inst.descriptions.get(sig, ''), at)}"
                       + (f"  # {_line(note)}" if note else ""))
    head = [f"# {_line(h)}" for h in header]
    head += ["plc:", f"  cycle: {format_ns(cycle_ns or 10_000_000)}", "drivers:"]
    named = {name for name, _, _ in drivers}
    for name, typ, config in drivers:
        flow = json.dumps({"type": typ, **{k: v for k, v in config.items() if k != "type"}},
                          ensure_ascii=False)
        head.append(f"  {_q(name)}: {flow}")
    if any(count.values()) and "sim" not in named or not named:
        head.append("  sim: {type: sim}")
    return "\n".join([*head, "instances:", *out]) + "\n"


def binding_at(note: str, address: str, typ: str, area: str) -> tuple[str, str]:
    """(the comment beside a binding, its ``at:``): a file's address the binding can carry
    (``%IX0.3`` for a bool input, ``%QW2`` for an int output ...) is its ``at:`` and leaves
    the comment; another (``%MW4``, ``%IX0.3`` on an output) stays in the comment only."""
    found = parse_located(address) if address else "none"
    if isinstance(found, str) or found.area != area or found.size not in (
            ("X",) if typ == "bool" else ("W", "D") if typ in ("int", "real") else ()):
        return note, ""
    if note == f"{address} in the PLCopen file":
        note = ""
    return note.replace(f", {address}", ""), str(found)


def _binding(source: str, invert: bool, description: str, at: str = "") -> str:
    """A binding as YAML flow text (``source`` and ``at`` quoted when YAML needs it: they
    may come from a file's softplc data)."""
    if not invert and not description and not at:
        return _q(source)
    parts = [f"from: {_q(source)}"]
    if invert:
        parts.append("invert: true")
    if at:
        parts.append(f"at: {json.dumps(at)}")
    if description:
        parts.append(f"description: {json.dumps(description, ensure_ascii=False)}")
    return "{" + ", ".join(parts) + "}"


def _line(text: str) -> str:
    """A text as one line of a YAML comment."""
    return " ".join("".join(c if c.isprintable() else " " for c in text).split())


def _q(text: str) -> str:
    """A name or a file name as a YAML scalar (quoted when YAML would read it otherwise)."""
    dumped: str = yaml.safe_dump(text, default_flow_style=True, allow_unicode=True)
    return dumped.strip().removesuffix("...").strip()
