"""The controller's alarms as OPC UA Alarms and Conditions (docs/opcua.md, "Alarms").

The alarm board lives in the controller (runtime/controller/alarms.py); the feed sends
each change of an alarm as a line of its own, in order (``change``: one event each, even
for a state that lasted less than a sample or came while this server's event loop was
stalled), and the whole board with the controller's status (``update``: the conditions
to create, and the state after a (re)connection; a state already shown by a change's
line fires nothing again). Here each condition is an object of type
AlarmConditionType (``ns=2;s=alarm.KEY``, under an ``Alarms`` folder of its source: the
instance, the driver or the Controller object), and every change of its state is an
event of the Server object (where alarm lists subscribe; SourceNode and SourceName name
the source) with its ConditionId, ConditionName (the key), Message, Severity, Retain,
EnabledState, ActiveState, AckedState and ConfirmedState (Id and text), Comment and
ClientUserId (who acknowledged or confirmed it last), Time (the change, controller's
clock).

- ``ConditionRefresh`` (and ConditionRefresh2): the conditions to show (Retain: active,
  or not yet acknowledged or confirmed), between RefreshStart and RefreshEnd events;
- ``Acknowledge`` and ``Confirm`` (AcknowledgeableConditionType's methods, called with the
  ConditionId as ObjectId, the EventId of the condition's last event and a comment):
  writers only (BadUserAccessDenied), forwarded to the controller (the feed's ``alarm``),
  whose refusal is the status (BadConditionBranchAlreadyAcked, ...; BadEventIdUnknown
  for an EventId that is not the condition's last). The new state comes back as the
  feed's line of that change, as an event.
"""

from __future__ import annotations

import copy
import datetime
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from asyncua import ua
from asyncua.common.node import Node
from asyncua.server.event_generator import EventGenerator

from runtime.opcua.methods import CALLER, identity
from runtime.opcua.space import nid, qname

if TYPE_CHECKING:
    from runtime.opcua.server import PlantServer

log = logging.getLogger(__name__)

#: a condition's class by the kind of alarm: the process's, or the system's
CLASSES = {"sfcerror": ua.ObjectIds.ProcessConditionClassType,
           "maxtime": ua.ObjectIds.ProcessConditionClassType,
           "driver": ua.ObjectIds.SystemConditionClassType,
           "fault": ua.ObjectIds.SystemConditionClassType,
           "overruns": ua.ObjectIds.SystemConditionClassType}
_TEXTS = {"ActiveState": ("Active", "Inactive"), "AckedState": ("Acknowledged",
                                                                  "Unacknowledged"),
          "ConfirmedState": ("Confirmed", "Unconfirmed")}


@dataclass
class _Condition:
    key: str
    node: ua.NodeId
    gen: EventGenerator
    #: the last state shown (active, acked, confirmed, severity, message, comment, by,
    #: time)
    shown: tuple[Any, ...] | None = None


class Conditions:
    """The conditions of one server (``setup`` before ``server.start()``)."""

    def __init__(self, ps: PlantServer) -> None:
        self.ps = ps
        self._by_key: dict[str, _Condition] = {}
        self._by_node: dict[ua.NodeId, _Condition] = {}
        self._template: Any = None

    async def setup(self) -> None:
        """Acknowledge and Confirm answered here (ConditionRefresh is asyncua's, bound by
        ``bind_condition_methods`` before ``init``)."""
        isession = self.ps.server.iserver.isession
        isession.add_method_callback(
            ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge),
            self._method("ack"))
        isession.add_method_callback(
            ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Confirm),
            self._method("confirm"))

    # -- from the controller -------------------------------------------------------------
    async def update(self, alarms: list[dict[str, Any]]) -> None:
        """The board's conditions as the feed sent them: a node for each new one, an
        event for each one whose state changed."""
        for a in alarms:
            await self._show(a, quiet=True)

    async def change(self, a: dict[str, Any]) -> None:
        """One change of an alarm's state, as the feed sent it (in order): its event,
        unless that state is already shown (a status came with it first)."""
        await self._show(a, quiet=False)

    async def _show(self, a: dict[str, Any], quiet: bool) -> None:
        """An event if ``a``'s state is not the one shown; ``quiet``: a condition first
        seen quiet (inactive, acknowledged, confirmed) is shown without one."""
        c = self._by_key.get(a["key"])
        if c is None:
            c = await self._create(a)
        shown = (a["active"], a["acked"], a["confirmed"], a["severity"], a["message"],
                 a["comment"], a["by"], a["time"])
        if shown == c.shown:
            return
        first = c.shown is None
        c.shown = shown
        if quiet and first and not (a["active"] or not a["acked"] or not a["confirmed"]):
            return  # a quiet condition: nothing to tell until it changes
        await self._fire(c, a)

    async def _create(self, a: dict[str, Any]) -> _Condition:
        space, server = self.ps.space, self.ps.server
        key, kind, source = a["key"], a["kind"], a["source"]
        if source == "controller":
            parent, leaf = space.controller, key.split(".", 1)[1]
        elif kind == "driver":
            parent, leaf = space.drivers.get(source), "fault"
        else:
            parent, leaf = space.instances.get(source), key.split(".", 1)[1]
        if parent is None:  # a source this server's plant file does not have
            parent = server.nodes.objects
        folder = space.folders.get(f"{parent.nodeid.to_string()}/Alarms")
        if folder is None:
            folder = await parent.add_folder(nid(f"{parent.nodeid.Identifier}/Alarms"),
                                             qname("Alarms"))
            space.folders[f"{parent.nodeid.to_string()}/Alarms"] = folder
        item = ua.AddNodesItem(
            RequestedNewNodeId=nid(f"alarm.{key}"), BrowseName=qname(leaf),
            ParentNodeId=folder.nodeid, ReferenceTypeId=ua.NodeId(ua.ObjectIds.Organizes),
            NodeClass=ua.NodeClass.Object,
            TypeDefinition=ua.NodeId(ua.ObjectIds.AlarmConditionType))
        attrs = ua.ObjectAttributes()
        attrs.DisplayName = ua.LocalizedText(key)
        item.NodeAttributes = attrs
        result = (await server.iserver.isession.add_nodes([item]))[0]
        result.StatusCode.check()
        await parent.add_reference(result.AddedNodeId, ua.ObjectIds.HasCondition,
                                   forward=True, bidirectional=False)
        gen = EventGenerator(server.iserver.isession)
        if self._template is None:
            await gen.init(ua.ObjectIds.AlarmConditionType, ua.ObjectIds.Server)
            self._template = copy.deepcopy(gen.event)
        else:
            await gen.init(copy.deepcopy(self._template), ua.ObjectIds.Server,
                           add_generates_event=False)
        ev = gen.event
        ev.NodeId = result.AddedNodeId
        ev.SourceNode = parent.nodeid
        ev.SourceName = (await Node(server.iserver.isession, parent.nodeid)
                         .read_browse_name()).Name
        ev.ConditionName = key
        ev.ConditionClassId = ua.NodeId(CLASSES.get(kind, ua.ObjectIds.BaseConditionClassType))
        ev.ConditionClassName = ua.LocalizedText(
            "ProcessConditionClass" if CLASSES.get(kind) == ua.ObjectIds.ProcessConditionClassType
            else "SystemConditionClass")
        ev.BranchId = ua.NodeId()
        ev.EnabledState = ua.LocalizedText("Enabled")
        setattr(ev, "EnabledState/Id", True)
        ev.Quality = ua.StatusCode(ua.StatusCodes.Good)
        c = _Condition(key, result.AddedNodeId, gen)
        self._by_key[key] = c
        self._by_node[c.node] = c
        return c

    async def _fire(self, c: _Condition, a: dict[str, Any]) -> None:
        ev = c.gen.event
        for field, state in (("ActiveState", a["active"]), ("AckedState", a["acked"]),
                             ("ConfirmedState", a["confirmed"])):
            yes, no = _TEXTS[field]
            setattr(ev, field, ua.LocalizedText(yes if state else no))
            setattr(ev, f"{field}/Id", bool(state))
        ev.Retain = bool(a["active"] or not a["acked"] or not a["confirmed"])
        ev.LastSeverity = ev.Severity
        ev.Severity = int(a["severity"])
        ev.Comment = ua.LocalizedText(a["comment"])
        ev.ClientUserId = a["by"]
        when = datetime.datetime.fromtimestamp(float(a["time"] or 0.0), datetime.UTC)
        await c.gen.trigger(when, a["message"])

    # -- from clients ------------------------------------------------------------------
    def _method(self, action: str) -> Any:
        async def call(parent: ua.NodeId, *args: Any) -> ua.StatusCode:
            c = self._by_node.get(parent)
            if c is None:
                return ua.StatusCode(ua.StatusCodes.BadNodeIdUnknown)
            caller = CALLER.get()
            who = identity(caller)
            if caller is None or not self.ps.may_write(caller[0]):
                log.warning("opcua: %s of alarm %s refused to %s: writers only", action,
                            c.key, who)
                return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
            event_id = _value(args[0]) if args else None
            last = c.gen.event.EventId
            last = getattr(last, "Value", last)
            if event_id is not None and event_id != last:
                return ua.StatusCode(ua.StatusCodes.BadEventIdUnknown)
            comment = _value(args[1]) if len(args) > 1 else None
            text = getattr(comment, "Text", comment) or ""
            ok, said, code = await self.ps.ask("alarm", c.key, action, who, str(text))
            log.info("opcua: %s: %s", who, said)
            return ua.StatusCode(getattr(ua.StatusCodes, code, ua.StatusCodes.Good)
                                 if not ok else ua.StatusCodes.Good)
        return call


def _value(arg: Any) -> Any:
    return arg.Value if isinstance(arg, ua.Variant) else arg
