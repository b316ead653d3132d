"""The OPC UA server of a plant: an asyncua server in its own process, fed by the
controller's feed socket (runtime/controller/feed.py), never in the scan's way.

- It connects to the feed and reconnects forever; while disconnected every variable's
  status is BadNoCommunication (BadWaitingForInitialData before the first frame).
- One scan per update: the values of one frame are written in one run of the event loop,
  without a suspension point between them (``write_attribute_value`` only queues the
  notifications), each with the frame's source timestamp (the scan's wall-clock time). The
  subscriptions publish from their own tasks, so a publish sees all of a frame or none of
  it. A subscription's publishing interval is revised to at least ``sample`` (a requested
  0, "publish on every change", would publish in the middle of a frame).
- Writes: only the nodes of ``opcua: writable:`` (AccessLevel CurrentWrite) are forwarded
  to the feed; the controller's answer is the write's status. Any other value write is
  BadNotWritable.
- Events (BaseEventType, severity and message) derived from successive frames: SFCError
  set/cleared (on the instance object), driver fault/recovery (on the driver object),
  controller fault and its acknowledgement (on the Controller object). A change shorter
  than ``sample`` may not be seen.
"""

from __future__ import annotations

import asyncio
import datetime
import importlib
import logging
from collections.abc import Callable
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.permission_rules import User, UserRole

from runtime.controller.feedclient import FeedClient, FeedLost
from runtime.language.model import PlantDef
from runtime.opcua.space import (
    NAMESPACE,
    NS,
    TYPES,
    Space,
    build_fixed,
    build_names,
    from_ua,
    nid,
    to_ua,
)

log = logging.getLogger(__name__)

#: a write the controller has not answered in this long fails (BadTimeout), seconds
WRITE_TIMEOUT_S = 3.0
#: event severities (1-1000)
SEVERITY = {"fault": 900, "sfcerror": 700, "driver": 800, "cleared": 300}

Status = ua.StatusCodes
#: the user of the server's own writes (asyncua's default for its attribute service)
INTERNAL = User(role=UserRole.Admin)


class PlantServer:
    """``softplc opcua PLANT``: serve the plant's address space from its feed."""

    def __init__(self, pdef: PlantDef, endpoint: str | None = None,
                 feed: str | None = None) -> None:
        assert pdef.opcua is not None
        self.pdef = pdef
        self.opc = pdef.opcua
        self.endpoint = endpoint or self.opc.endpoint
        self.feed_path = feed or self.opc.feed
        self.server = Server()
        self.space = Space()
        #: the controller's feed (runtime/controller/feedclient.py): its state is the last
        #: frame
        self.feed = FeedClient(self.feed_path, "opcua", self._schema, self._frame, self._lost)
        self.state = self.feed.state
        #: may this session's user write? Only a writer (UserRole.User: a user with its
        #: password, or a trusted client certificate, runtime/opcua/security.py), checked
        #: here whatever the channel: asyncua skips its own permission rules on a channel
        #: a client never opened (HEL, then CreateSession), where any anonymous session
        #: could otherwise write
        self.may_write: Callable[[User], bool] = lambda user: user.role is UserRole.User
        self.connected = asyncio.Event()
        #: frames applied (tests wait on it)
        self.frames = 0
        self._names_built: list[tuple[str, ...]] | None = None
        self._events: dict[str, Any] = {}
        self._prev: dict[str, Any] = {}

    # -- set-up ------------------------------------------------------------------
    async def start(self) -> None:
        """Build the fixed part of the address space and open the endpoint."""
        srv = self.server
        await srv.init()
        srv.set_endpoint(self.endpoint)
        srv.set_server_name(f"softplc {self.pdef.path}")
        await self._security()
        idx = await srv.register_namespace(NAMESPACE)
        if idx != NS:
            raise RuntimeError(f"namespace {NAMESPACE} got index {idx}, expected {NS}")
        await build_fixed(srv, self.pdef, self.space)
        for name, obj in self.space.instances.items():
            self._events[f"i:{name}"] = await srv.get_event_generator(
                ua.ObjectIds.BaseEventType, obj)
        for name, obj in self.space.drivers.items():
            self._events[f"d:{name}"] = await srv.get_event_generator(
                ua.ObjectIds.BaseEventType, obj)
        assert self.space.controller is not None
        self._events["controller"] = await srv.get_event_generator(
            ua.ObjectIds.BaseEventType, self.space.controller)
        self._hook_writes()
        self._hook_subscriptions()
        await srv.start()
        log.info("OPC UA server on %s (feed %s)", self.endpoint, self.feed_path)

    async def _security(self) -> None:
        """Only policy None until the security module is there (runtime/opcua/security.py);
        with it, ``apply`` sets the policies, certificates and users."""
        try:
            security = importlib.import_module("runtime.opcua.security")
        except ModuleNotFoundError:
            security = None
        if security is not None:
            await security.apply(self.server, self.opc.security, self.opc.loc)
            return
        if "None" not in self.opc.security.policies:
            raise RuntimeError("opcua security: only policy None is available in this build: "
                               "list it in opcua: security: policies")
        self.server.set_security_policy([ua.SecurityPolicyType.NoSecurity])

    def _hook_writes(self) -> None:
        service = self.server.iserver.attribute_service
        plain = service.write
        internal = self.server.iserver.isession

        async def write(params: ua.WriteParameters,
                        user: User = INTERNAL) -> list[ua.StatusCode]:
            if user is internal.user:  # the server's own session: building the space
                return list(await plain(params, user=user))
            out: list[ua.StatusCode] = []
            for wv in params.NodesToWrite:
                if wv.NodeId.NamespaceIndex != NS:
                    p = ua.WriteParameters()
                    p.NodesToWrite = [wv]
                    out += await plain(p, user=user)
                elif wv.AttributeId != ua.AttributeIds.Value:
                    out.append(ua.StatusCode(Status.BadNotWritable))
                else:
                    out.append(await self._client_write(wv, user))
            return out
        service.write = write

    def _hook_subscriptions(self) -> None:
        """A publishing interval below ``sample`` is revised up to it (see the module)."""
        service = self.server.iserver.subscription_service
        plain = service.create_subscription
        least_ms = self.opc.sample_ns / 1e6

        async def create(params: ua.CreateSubscriptionParameters, *args: Any,
                         **kwargs: Any) -> ua.CreateSubscriptionResult:
            if params.RequestedPublishingInterval < least_ms:
                params.RequestedPublishingInterval = least_ms
            return await plain(params, *args, **kwargs)
        service.create_subscription = create

    # -- writes ------------------------------------------------------------------
    async def _client_write(self, wv: ua.WriteValue, user: User) -> ua.StatusCode:
        i = self.space.by_node.get(wv.NodeId)
        if i is None or self.space.names[i] not in self.opc.writable:
            return ua.StatusCode(Status.BadNotWritable)
        name = self.space.names[i]
        if not self.may_write(user):
            return ua.StatusCode(Status.BadUserAccessDenied)
        try:
            value = from_ua(self.space.types[i], wv.Value.Value)
        except (ValueError, TypeError, AttributeError):
            return ua.StatusCode(Status.BadTypeMismatch)
        try:
            ok, text = await self.feed.set(name, value, WRITE_TIMEOUT_S)
        except TimeoutError:
            return ua.StatusCode(Status.BadTimeout)
        except (OSError, FeedLost):
            return ua.StatusCode(Status.BadNoCommunication)
        if not ok:
            log.info("opcua write of %s refused by the controller: %s", name, text)
            return ua.StatusCode(Status.BadInvalidState)
        return ua.StatusCode(Status.Good)

    # -- the feed ----------------------------------------------------------------
    async def run(self) -> None:
        """Follow the feed until ``stop()``: reconnect forever."""
        await self.feed.run()

    def stop(self) -> None:
        """End ``run()``: the feed connection is closed (a read waiting on it ends)."""
        self.feed.stop()

    async def _lost(self) -> None:
        """The feed's connection ended: every value BadNoCommunication until it is back."""
        self.connected.clear()
        self._prev = {}  # the next frame is a state, not a change from this one
        await self._all_bad(Status.BadNoCommunication)

    async def _schema(self, schema: dict[str, Any]) -> None:
        names = [tuple(n) for n in schema["names"]]
        if names != self._names_built:  # names, types and roles: an online change
            await build_names(schema, self.space, lambda n: n in self.opc.writable,
                              self.server)
            self._names_built = names
            log.info("address space: %d plant names", len(names))
        self.connected.set()

    async def _frame(self) -> None:
        """Every value of the frame, one batch, the frame's source timestamp. No await in
        here suspends (see the module docstring): a publish never splits the batch."""
        st, space = self.state, self.space
        ts = datetime.datetime.fromtimestamp(st.wall, datetime.UTC)
        now = datetime.datetime.now(datetime.UTC)
        write = self.server.iserver.aspace.write_attribute_value
        value_attr = ua.AttributeIds.Value
        for i, node_id in enumerate(space.nodes):
            ptype = space.types[i]
            await write(node_id, value_attr, _dv(ptype, to_ua(ptype, st.values[i]), ts, now))
        c = st.status
        lat = c.get("lateness_us") or {}
        ctl = {"state": c.get("state", ""), "fault": c.get("fault") or "",
               "cycle": c.get("cycle_ms", 0.0), "scan": st.scan, "scans": st.scan + 1,
               "overruns": c.get("overruns", 0), "lateness_p50": lat.get("p50", 0.0),
               "lateness_p99": lat.get("p99", 0.0), "lateness_max": lat.get("max", 0.0),
               "uptime": float(c.get("uptime_s", 0))}
        for key, value in ctl.items():
            ptype = space.all_vars[nid(f"controller.{key}")]
            await write(nid(f"controller.{key}"), value_attr, _dv(ptype, value, ts, now))
        for dname, (health, reason, _ok) in (c.get("drivers") or {}).items():
            if dname in space.drivers:
                await write(nid(f"driver.{dname}.health"), value_attr,
                            _dv("string", health, ts, now))
                await write(nid(f"driver.{dname}.fault"), value_attr,
                            _dv("string", reason, ts, now))
        self.frames += 1
        await self._derive_events(ts)

    async def _all_bad(self, code: int) -> None:
        dv = ua.DataValue(StatusCode=ua.StatusCode(code),
                          SourceTimestamp=datetime.datetime.now(datetime.UTC))
        write = self.server.iserver.aspace.write_attribute_value
        for node_id in self.space.all_vars:
            await write(node_id, ua.AttributeIds.Value, dv)

    # -- events ------------------------------------------------------------------
    async def _derive_events(self, ts: datetime.datetime) -> None:
        st, prev = self.state, self._prev
        now: dict[str, Any] = {}
        for name in self.space.instances:
            key = f"{name}.SFCError"
            if key in st.index:
                now[f"i:{name}"] = (st.get(key), st.get(f"{name}.SFCErrorStep")
                                    if f"{name}.SFCErrorStep" in st.index else "")
        for dname, (health, reason, _ok) in (st.status.get("drivers") or {}).items():
            now[f"d:{dname}"] = (health, reason)
        now["controller"] = (st.status.get("state"), st.status.get("fault"))
        self._prev = now
        if not prev:
            return  # the first frame after a (re)connection: a state, not a change
        for key, value in now.items():
            old = prev.get(key)
            if old is None or old == value or key not in self._events:
                continue
            message, severity = _event_text(key, old, value)
            if message:
                gen = self._events[key]
                gen.event.Severity = severity
                await gen.trigger(ts, message)


def _event_text(key: str, old: Any, new: Any) -> tuple[str, int]:
    """The event's message and severity for a change of ``key`` ("" if none)."""
    if key.startswith("i:"):
        name = key[2:]
        if new[0] and not old[0]:
            return (f"{name}: SFCError set{f' (step {new[1]})' if new[1] else ''}",
                    SEVERITY["sfcerror"])
        if old[0] and not new[0]:
            return f"{name}: SFCError cleared", SEVERITY["cleared"]
        return "", 0
    if key.startswith("d:"):
        name = key[2:]
        if new[0] == "fault":
            return f"driver {name}: fault: {new[1]}", SEVERITY["driver"]
        if old[0] == "fault":
            return f"driver {name}: recovered ({new[0]})", SEVERITY["cleared"]
        return "", 0
    state, fault = new
    if state in ("fault", "halted") and old[0] not in ("fault", "halted"):
        return f"controller {state}: {fault}", SEVERITY["fault"]
    if old[0] in ("fault", "halted") and state not in ("fault", "halted"):
        return f"controller: {old[0]} acknowledged, now {state}", SEVERITY["cleared"]
    return "", 0


def _dv(ptype: str, value: Any, ts: datetime.datetime,
        now: datetime.datetime) -> ua.DataValue:
    return ua.DataValue(ua.Variant(value, TYPES[ptype][0]), SourceTimestamp=ts,
                        ServerTimestamp=now)


async def serve(pdef: PlantDef, endpoint: str | None = None, feed: str | None = None,
                ready: Callable[[PlantServer], None] | None = None,
                stop: asyncio.Event | None = None) -> None:
    """Run the server until ``stop`` is set (or forever)."""
    ps = PlantServer(pdef, endpoint, feed)
    await ps.start()
    task = asyncio.create_task(ps.run())
    if ready is not None:
        ready(ps)
    try:
        if stop is None:
            await task
        else:
            await stop.wait()
            ps.stop()
            await task
    finally:
        await ps.server.stop()
