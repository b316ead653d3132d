"""The OPC UA address space of a plant (docs/opcua.md, "Address space"): NodeIds, data
types, and the tree built under Objects.

NodeIds are strings in namespace 2 (``urn:softplc:plant``):

- every plant name is its own NodeId: ``ns=2;s=tester1.iMarcha``,
  ``ns=2;s=tester1.gsAbrir.X``, ``ns=2;s=tester1.gsAbrir.T``, ``ns=2;s=sim.I0``,
  ``ns=2;s=sim.ok``;
- objects and folders: ``ns=2;s=tester1`` (an instance), ``ns=2;s=tester1/Inputs`` (its
  folders: Inputs, Outputs, Memory, Steps, Flags), ``ns=2;s=tester1.gsAbrir`` (a step),
  ``ns=2;s=driver.sim`` (a driver), ``ns=2;s=controller``;
- a driver's health: ``ns=2;s=driver.sim.health``, ``ns=2;s=driver.sim.fault``;
- the controller: ``ns=2;s=controller.state`` (``.fault``, ``.cycle``, ``.scan``,
  ``.scans``, ``.overruns``, ``.lateness_p50``, ``.lateness_p99``, ``.lateness_max``,
  ``.uptime``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from asyncua import Server, ua
from asyncua.common.node import Node

from runtime.controller.feed import value_problem
from runtime.errors import SoftplcError
from runtime.language import ast as A
from runtime.language.iolist import IOList, Meaning
from runtime.language.model import PlantDef
from runtime.language.units import CEFACT_URI
from runtime.language.yamlsrc import TIME_MAX_NS

NAMESPACE = "urn:softplc:plant"
NS = 2
#: plant type (language.ast.Type value) -> (variant type, data type NodeId)
TYPES: dict[str, tuple[ua.VariantType, int]] = {
    "bool": (ua.VariantType.Boolean, ua.ObjectIds.Boolean),
    "int": (ua.VariantType.Int64, ua.ObjectIds.Int64),
    "real": (ua.VariantType.Double, ua.ObjectIds.Double),
    "time": (ua.VariantType.Double, ua.ObjectIds.Duration),
    "string": (ua.VariantType.String, ua.ObjectIds.String),
}
#: plant type name -> the language's type
PLANT_TYPES = {t.value: t for t in A.Type}
#: a value of each type for the creation of its node (its status is bad until a frame)
ZERO: dict[str, Any] = {"bool": False, "int": 0, "real": 0.0, "time": 0.0, "string": ""}
#: the role of a name in the feed's schema -> the instance folder it goes in
FOLDERS = {"input": "Inputs", "output": "Outputs", "memory": "Memory", "temporary": "Memory",
           "chart flag": "Flags", "system value": "Flags"}
#: the Controller object's variables: name -> (plant type, description)
CONTROLLER_VARS = {
    "state": ("string", "starting, running, paused, stepping, iocheck, fault, halted, stopped"),
    "fault": ("string", "the fault or halt reason, empty when none"),
    "cycle": ("time", "the cycle, ms"),
    "scan": ("int", "the number of the scan the values come from (the trace's cycle)"),
    "scans": ("int", "scans run since the controller started"),
    "overruns": ("int", "scans that ended after their deadline"),
    "lateness_p50": ("real", "scan start lateness, median over the last cycles, us"),
    "lateness_p99": ("real", "scan start lateness, 99th percentile, us"),
    "lateness_max": ("real", "scan start lateness, maximum, us"),
    "uptime": ("real", "seconds since the controller started"),
}
DRIVER_VARS = {"health": ("string", "ok, degraded or fault"),
               "fault": ("string", "why the driver is not ok, empty when it is")}


def nid(text: str) -> ua.NodeId:
    return ua.NodeId(text, NS)


def qname(text: str) -> ua.QualifiedName:
    return ua.QualifiedName(text, NS)


#: what an Int64 holds
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1
GOOD = ua.StatusCodes.Good
OUT_OF_RANGE = ua.StatusCodes.BadOutOfRange


class OutOfRange(SoftplcError, ValueError):
    """A client's value of the right type that no plant variable may hold (BadOutOfRange)."""


def to_ua(ptype: str, value: Any) -> tuple[Any, int]:
    """A feed value (times in ns) -> (the node's value (times in ms), its status code).
    An INT beyond Int64, a TIME beyond 64-bit nanoseconds, or a REAL beyond a Double is
    (None, BadOutOfRange) (docs/opcua.md, "Values out of range"): the language's integers
    have no fixed width, OPC UA's have; and a Bad value carries no value (Part 4, 7.7.1)."""
    if ptype == "int":
        if INT64_MIN <= value <= INT64_MAX:
            return value, GOOD
        return None, OUT_OF_RANGE
    if ptype == "time":
        if -TIME_MAX_NS <= value <= TIME_MAX_NS:
            return value / 1e6, GOOD
        return None, OUT_OF_RANGE
    if ptype == "real":
        try:
            return float(value), GOOD
        except OverflowError:  # an integer past a Double (a REAL holds floats only)
            return None, OUT_OF_RANGE
    return value, GOOD


def from_ua(ptype: str, variant: ua.Variant) -> Any:
    """A client's written Variant -> the feed value; ValueError on a type mismatch,
    OutOfRange for a value of the right type no plant variable may hold (a non-finite
    REAL or TIME, a TIME past 64-bit nanoseconds: ``controller.feed.value_problem``)."""
    vt, _ = TYPES[ptype]
    if variant.VariantType != vt:
        raise ValueError(f"expected {vt.name}, found {variant.VariantType.name}")
    value = variant.Value
    if ptype == "time":
        if not math.isfinite(value):
            raise OutOfRange(f"{value!r} ms is not a finite time")
        value = round(value * 1e6)
    problem = value_problem(PLANT_TYPES[ptype], value)
    if problem is not None:
        raise OutOfRange(problem)
    return value


@dataclass
class Space:
    """The nodes of one plant: the plant names (in feed order), driver and controller
    variables, and the objects events come from."""

    names: list[str] = field(default_factory=list)
    types: list[str] = field(default_factory=list)
    #: feed index -> NodeId
    nodes: list[ua.NodeId] = field(default_factory=list)
    by_node: dict[ua.NodeId, int] = field(default_factory=dict)
    #: every variable NodeId (plant names, drivers, controller) -> its plant type
    all_vars: dict[ua.NodeId, str] = field(default_factory=dict)
    #: object NodeIds: instance -> node, driver -> node, "controller"
    instances: dict[str, Node] = field(default_factory=dict)
    drivers: dict[str, Node] = field(default_factory=dict)
    controller: Node | None = None
    #: the plant-name variables created, name -> (type, role), and the folders and step
    #: objects holding them: an online change adds and removes only what changed
    built: dict[str, tuple[str, str]] = field(default_factory=dict)
    folders: dict[str, Node] = field(default_factory=dict)
    steps: dict[str, Node] = field(default_factory=dict)
    #: the plant file's I/O list (what each name means), read at the server's start
    iolist: IOList | None = None
    #: the reference type from a driver point to the signal bound to it
    bound: ua.NodeId | None = None


async def _describe(node: Node, text: str) -> None:
    await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(
        ua.Variant(ua.LocalizedText(text), ua.VariantType.LocalizedText)))


async def _var(parent: Node, text: str, leaf: str, ptype: str, space: Space,
               meaning: Meaning | str = "") -> Node:
    """A variable of the plant, status BadWaitingForInitialData, with its Description,
    and, for a number with a unit or a range, its EngineeringUnits (UN/CEFACT) and EURange
    properties (as an AnalogItem has them)."""
    m = Meaning(meaning) if isinstance(meaning, str) else meaning
    vt, dt = TYPES[ptype]
    node = await parent.add_variable(nid(text), qname(leaf), ua.Variant(ZERO[ptype], vt),
                                     datatype=ua.NodeId(dt))
    await node.write_attribute(ua.AttributeIds.Value, ua.DataValue(
        StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
    if m.description:
        await _describe(node, m.description)
    if m.unit is not None and ptype in ("int", "real", "time"):
        eu = ua.EUInformation(NamespaceUri=CEFACT_URI, UnitId=m.unit.unit_id,
                              DisplayName=ua.LocalizedText(m.unit.symbol),
                              Description=ua.LocalizedText(m.unit.name))
        await node.add_property(nid(f"{text}.EngineeringUnits"),
                                qname("EngineeringUnits"), eu,
                                datatype=ua.NodeId(ua.ObjectIds.EUInformation))
    if m.range is not None and ptype in ("int", "real"):
        await node.add_property(nid(f"{text}.EURange"), qname("EURange"),
                                ua.Range(Low=m.range[0], High=m.range[1]),
                                datatype=ua.NodeId(ua.ObjectIds.Range))
    space.all_vars[nid(text)] = ptype
    return node


def meaning_of(space: Space, name: str) -> Meaning:
    return space.iolist.meaning(name) if space.iolist is not None else Meaning()


async def build_fixed(server: Server, pdef: PlantDef, space: Space) -> None:
    """What the plant file alone gives: one object per instance (its chart's description)
    and per driver, and the Controller object with its variables."""
    objects = server.nodes.objects
    space.iolist = IOList(pdef)
    space.bound = nid("BoundSignal")
    refs = server.get_node(ua.NodeId(ua.ObjectIds.NonHierarchicalReferences))
    await refs.add_reference_type(space.bound, qname("BoundSignal"), symmetric=False,
                                  inversename="BoundPoint")
    for name, idef in pdef.instances.items():
        obj = await objects.add_object(nid(name), qname(name))
        text = (idef.description or idef.grafcet.description
                or f"instance of chart {idef.grafcet.name}")
        await _describe(obj, text)
        space.instances[name] = obj
    for dname, ddef in pdef.drivers.items():
        obj = await objects.add_object(nid(f"driver.{dname}"), qname(dname))
        await _describe(obj, f"driver {dname} ({ddef.type})")
        for leaf, (ptype, text) in DRIVER_VARS.items():
            await _var(obj, f"driver.{dname}.{leaf}", leaf, ptype, space, text)
        space.drivers[dname] = obj
    ctl = await objects.add_object(nid("controller"), qname("Controller"))
    for leaf, (ptype, text) in CONTROLLER_VARS.items():
        await _var(ctl, f"controller.{leaf}", leaf, ptype, space, text)
    space.controller = ctl


async def build_names(schema: dict[str, Any], space: Space,
                      writable: Callable[[str], bool], server: Server | None = None) -> None:
    """The plant names of the feed's schema under their instance or driver objects, in
    feed order. Called again with a new schema (an online change): the variables of names
    gone, or whose type or role changed, get the status BadNodeIdUnknown (what a
    subscription to them shows last) and are deleted; new ones are added; every other
    node stays as it is, with its subscriptions."""
    entries = [(str(t), str(p), str(r)) for t, p, r in schema["names"]]
    want = {t: (p, r) for t, p, r in entries}
    gone = [t for t, pr in space.built.items() if want.get(t) != pr]
    if gone and server is not None:
        await _remove(server, space, gone)
    space.names = [t for t, _, _ in entries]
    space.types = [p for _, p, _ in entries]
    space.nodes = [nid(t) for t in space.names]
    space.by_node = {node_id: i for i, node_id in enumerate(space.nodes)}
    added = []
    for text, ptype, role in entries:
        if text not in space.built and await _add(space, text, ptype, role, writable):
            space.built[text] = (ptype, role)
            added.append(text)
    if server is not None:
        await _bind(server, space, added)


async def _bind(server: Server, space: Space, names: list[str]) -> None:
    """A BoundSignal reference from each driver point of ``names`` to the signals bound
    to it (inverse BoundPoint), as the plant file's I/O list says."""
    if space.iolist is None or space.bound is None:
        return
    for text in names:
        for row in space.iolist.bound_to(text):
            if row.signal in space.built:
                await server.get_node(nid(text)).add_reference(
                    nid(row.signal), space.bound, forward=True, bidirectional=True)


async def _add(space: Space, text: str, ptype: str, role: str,
               writable: Callable[[str], bool]) -> bool:
    """The variable of one plant name; False if its instance is not in this plant file."""
    head, _, rest = text.partition(".")
    if head in space.drivers and role in ("point in", "point out", "driver health"):
        parent = space.drivers[head]
        if role != "driver health":
            key = f"driver.{head}/{'Inputs' if role == 'point in' else 'Outputs'}"
            parent = await _folder(space.drivers[head], key, key.rsplit("/", 1)[1], space)
        await _var(parent, text, rest, ptype, space, meaning_of(space, text))
        return True
    inst = space.instances.get(head)
    if inst is None:
        return False  # not in this plant file (a newer schema): left out
    if role in ("step", "step time"):
        step, leaf = rest.rsplit(".", 1)
        fold = await _folder(inst, f"{head}/Steps", "Steps", space)
        obj = space.steps.get(f"{head}.{step}")
        if obj is None:
            obj = await fold.add_object(nid(f"{head}.{step}"), qname(step))
            said = meaning_of(space, f"{head}.{step}").description
            if said:
                await _describe(obj, said)
            space.steps[f"{head}.{step}"] = obj
        m = meaning_of(space, text)
        what = "step active" if leaf == "X" else "time the step has been active, ms"
        await _var(obj, text, leaf, ptype, space,
                   Meaning(f"{m.description}: {what}" if m.description else what, m.unit))
        return True
    fname = FOLDERS.get(role, "Memory")
    fold = await _folder(inst, f"{head}/{fname}", fname, space)
    node = await _var(fold, text, rest, ptype, space, meaning_of(space, text))
    if writable(text):
        await node.set_writable(True)
    return True


async def _remove(server: Server, space: Space, names: list[str]) -> None:
    """Delete the variables of ``names`` (and a step's object once neither its X nor its
    T is left), after a last BadNodeIdUnknown for their subscribers."""
    gone = ua.DataValue(StatusCode=ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown))
    for text in names:
        node = server.get_node(nid(text))
        await node.write_attribute(ua.AttributeIds.Value, gone)
    await server.delete_nodes([server.get_node(nid(t)) for t in names], recursive=True)
    for text in names:
        space.all_vars.pop(nid(text), None)
        del space.built[text]
    left = {t.rsplit(".", 1)[0] for t, (_, role) in space.built.items()
            if role in ("step", "step time")}
    for key in [k for k in space.steps if k not in left]:
        await server.delete_nodes([space.steps.pop(key)], recursive=True)


async def _folder(parent: Node, key: str, name: str, space: Space) -> Node:
    f = space.folders.get(key)
    if f is None:
        f = await parent.add_folder(nid(key), qname(name))
        space.folders[key] = f
    return f
