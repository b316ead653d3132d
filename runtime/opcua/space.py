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

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from asyncua import Server, ua
from asyncua.common.node import Node

from runtime.language.model import PlantDef

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


def to_ua(ptype: str, value: Any) -> Any:
    """A feed value (times in ns) -> the node's value (times in ms)."""
    if ptype == "time":
        return value / 1e6
    if ptype == "real":
        return float(value)
    return value


def from_ua(ptype: str, variant: ua.Variant) -> Any:
    """A client's written Variant -> the feed value; ValueError on a type mismatch."""
    vt, _ = TYPES[ptype]
    if variant.VariantType != vt:
        raise ValueError(f"expected {vt.name}, found {variant.VariantType.name}")
    if ptype == "time":
        return round(variant.Value * 1e6)
    return variant.Value


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
    #: nodes created for the schema (removed when it changes)
    created: list[Node] = field(default_factory=list)


async def _var(parent: Node, text: str, leaf: str, ptype: str, space: Space,
               description: str = "") -> Node:
    vt, dt = TYPES[ptype]
    node = await parent.add_variable(nid(text), qname(leaf), ua.Variant(ZERO[ptype], vt),
                                     datatype=ua.NodeId(dt))
    await node.write_attribute(ua.AttributeIds.Value, ua.DataValue(
        StatusCode=ua.StatusCode(ua.StatusCodes.BadWaitingForInitialData)))
    if description:
        await node.write_attribute(ua.AttributeIds.Description, ua.DataValue(
            ua.Variant(ua.LocalizedText(description), ua.VariantType.LocalizedText)))
    space.all_vars[nid(text)] = ptype
    return node


async def build_fixed(server: Server, pdef: PlantDef, space: Space) -> None:
    """What the plant file alone gives: one object per instance (its chart's description)
    and per driver, and the Controller object with its variables."""
    objects = server.nodes.objects
    for name, idef in pdef.instances.items():
        obj = await objects.add_object(nid(name), qname(name))
        text = idef.grafcet.description or f"instance of chart {idef.grafcet.name}"
        await obj.write_attribute(ua.AttributeIds.Description, ua.DataValue(
            ua.Variant(ua.LocalizedText(text), ua.VariantType.LocalizedText)))
        space.instances[name] = obj
    for dname, ddef in pdef.drivers.items():
        obj = await objects.add_object(nid(f"driver.{dname}"), qname(dname))
        await obj.write_attribute(ua.AttributeIds.Description, ua.DataValue(
            ua.Variant(ua.LocalizedText(f"driver {dname} ({ddef.type})"),
                       ua.VariantType.LocalizedText)))
        for leaf, (ptype, text) in DRIVER_VARS.items():
            await _var(obj, f"driver.{dname}.{leaf}", leaf, ptype, space, text)
        space.drivers[dname] = obj
    ctl = await objects.add_object(nid("controller"), qname("Controller"))
    for leaf, (ptype, text) in CONTROLLER_VARS.items():
        await _var(ctl, f"controller.{leaf}", leaf, ptype, space, text)
    space.controller = ctl


async def build_names(schema: dict[str, Any], space: Space,
                      writable: Callable[[str], bool]) -> None:
    """The plant names of the feed's schema under their instance or driver objects."""
    folders: dict[str, Node] = {}
    steps: dict[str, Node] = {}
    space.names, space.types, space.nodes, space.by_node = [], [], [], {}
    for text, ptype, role in schema["names"]:
        head, _, rest = text.partition(".")
        space.names.append(text)
        space.types.append(ptype)
        node_id = nid(text)
        space.nodes.append(node_id)
        space.by_node[node_id] = len(space.nodes) - 1
        if head in space.drivers and role in ("point in", "point out", "driver health"):
            parent = space.drivers[head]
            if role != "driver health":
                key = f"driver.{head}/{'Inputs' if role == 'point in' else 'Outputs'}"
                parent = await _folder(space.drivers[head], key, key.rsplit("/", 1)[1],
                                       folders, space)
            await _var(parent, text, rest, ptype, space)
            continue
        inst = space.instances.get(head)
        if inst is None:
            continue  # not in this plant file (a newer schema): left out
        if role in ("step", "step time"):
            step, leaf = rest.rsplit(".", 1)
            fold = await _folder(inst, f"{head}/Steps", "Steps", folders, space)
            obj = steps.get(f"{head}.{step}")
            if obj is None:
                obj = await fold.add_object(nid(f"{head}.{step}"), qname(step))
                steps[f"{head}.{step}"] = obj
            await _var(obj, text, leaf, ptype, space,
                       "step active" if leaf == "X" else "time the step has been active, ms")
            continue
        fname = FOLDERS.get(role, "Memory")
        fold = await _folder(inst, f"{head}/{fname}", fname, folders, space)
        node = await _var(fold, text, rest, ptype, space)
        if writable(text):
            await node.set_writable(True)


async def _folder(parent: Node, key: str, name: str, folders: dict[str, Node],
                  space: Space) -> Node:
    f = folders.get(key)
    if f is None:
        f = await parent.add_folder(nid(key), qname(name))
        folders[key] = f
        space.created.append(f)
    return f


async def clear_names(server: Server, space: Space) -> None:
    """Remove what ``build_names`` made (the schema changed)."""
    if space.created:
        await server.delete_nodes(space.created, recursive=True)
    for node_id in space.nodes:
        space.all_vars.pop(node_id, None)
    space.created = []
    for dname, obj in space.drivers.items():
        for child in await obj.get_children():
            if child.nodeid.Identifier not in (f"driver.{dname}.health",
                                               f"driver.{dname}.fault") and (
                    child.nodeid in space.by_node):
                await server.delete_nodes([child], recursive=True)
    space.names, space.types, space.nodes, space.by_node = [], [], [], {}
