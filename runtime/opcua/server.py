"""The OPC UA server of a plant: an asyncua server in its own process, fed by the
controller's feed socket (runtime/controller/feed.py), never in the scan's way.

- It connects to the feed and reconnects forever; while disconnected every variable's
  status is BadNoCommunication (BadWaitingForInitialData before the first frame).
- One scan per update: the values of one frame that changed (value or status) are written
  in one run of the event loop, without a suspension point between them
  (``write_attribute_value`` only queues the notifications), each with the frame's source
  timestamp (the scan's wall-clock time); an unchanged value is not written again (its
  SourceTimestamp stays the scan of its last change): with clients holding every variable
  of a large plant, writing all of them each frame cost more than a sample. The
  subscriptions publish from their own tasks, so a publish sees all of a frame or none of
  it. A subscription's publishing interval is revised to at least ``sample`` (a requested
  0, "publish on every change", would publish in the middle of a frame: limits.py).
- Stale values: when no frame came for ``stale_after_s`` (the controller is frozen,
  stopped by a signal, or stuck in a scan while its watchdog holds the outputs off),
  every variable turns BadOutOfService (no value: a Bad value carries none), with the
  last frame's SourceTimestamp, until the next frame. A value OPC UA cannot carry (an
  INT beyond Int64) is BadOutOfRange (``space.to_ua``).
- Writes: only the nodes of ``opcua: writable:`` (AccessLevel CurrentWrite) are forwarded
  to the feed; the controller's answer is the write's status. Any other value write is
  BadNotWritable; a value out of range (a non-finite REAL or TIME, a TIME past 64-bit
  nanoseconds) BadOutOfRange.
- Clients are held to ``opcua: limits:`` (limits.py). The server lowers its own CPU
  priority to SERVER_NICE, wherever it is started (its unit sets the same).
- Events (BaseEventType, severity and message) derived from successive frames: SFCError
  set/cleared (on the instance object), driver fault/recovery (on the driver object),
  controller fault and its acknowledgement (on the Controller object). A change shorter
  than ``sample`` may not be seen.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
import os
from collections.abc import Callable
from typing import Any

from asyncua import Server, ua
from asyncua.common.callback import CallbackType, ServerItemCallback
from asyncua.crypto.permission_rules import User, UserRole

from runtime.controller.feedclient import FeedClient, FeedLost
from runtime.language.flagtexts import sfcerror_cause
from runtime.language.model import PlantDef
from runtime.language.opcuaconf import check_security
from runtime.opcua.conditions import Conditions
from runtime.opcua.limits import Limits
from runtime.opcua.methods import Methods, track_callers
from runtime.opcua.security import apply as apply_security
from runtime.opcua.security import read_credentials
from runtime.opcua.space import (
    NAMESPACE,
    NS,
    TYPES,
    OutOfRange,
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
#: values are stale when no frame came for this many samples, and at least STALE_MIN_S
STALE_SAMPLES = 4
STALE_MIN_S = 1.0
#: the niceness the server gives itself (as its systemd unit's Nice=): the controller's
#: scan, at niceness 0 or real time, gets the CPU first
SERVER_NICE = 10

Status = ua.StatusCodes
#: AccessLevel bits: CurrentRead, CurrentRead | CurrentWrite
READ_ONLY, READ_WRITE = 1, 3
#: the status of every value while the controller sends no frame
STALE = Status.BadOutOfService


def stale_after_s(sample_ns: int) -> float:
    """How long without a frame makes the values stale, seconds (checked every sample)."""
    return max(STALE_SAMPLES * sample_ns / 1e9, STALE_MIN_S)

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
        #: the certificate and key, read first: a file that is wrong is said at once (a
        #: SourceError at its line), not after asyncua's seconds of set-up
        check_security(self.opc.security)
        self.credentials = read_credentials(self.opc.security, self.opc.loc)
        self.server = Server()
        self.space = Space()
        #: the controller's feed (runtime/controller/feedclient.py): its state is the last
        #: frame
        self.feed = FeedClient(self.feed_path, "opcua", self._schema, self._frame, self._lost,
                               self._status, plant=pdef, alarm=self._alarm)
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
        #: the instances' SFCError as the last frame showed them (events at frames)
        self._prev: dict[str, Any] = {}
        #: the drivers' health and the controller's state as the last status said them
        #: (events at statuses); None: no status since the (re)connection
        self._prev_status: dict[str, Any] | None = None
        #: per plant variable (``space.nodes``), the feed value last written and the status
        #: it was written with (None: its own): a frame writes only what changed
        self._shown: list[tuple[Any, int | None]] = []
        self.limits = Limits(self.server, self.opc.limits, self.opc.sample_ns)
        self.methods = Methods(self)
        self.conditions = Conditions(self)
        #: event-loop time of the last frame (None: none since the (re)connection, or a
        #: schema being built); whether the values are shown stale now
        self._last_frame: float | None = None
        self.stale = False

    # -- set-up ------------------------------------------------------------------
    async def start(self) -> None:
        """Build the fixed part of the address space and open the endpoint."""
        srv = self.server
        srv.iserver.bind_condition_methods = True  # ConditionRefresh (conditions.py)
        await srv.init()
        srv.set_endpoint(self.endpoint)
        srv.set_server_name(f"softplc {self.pdef.path}")
        await apply_security(srv, self.opc.security, self.opc.loc, self.credentials)
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
        await self.methods.build()
        await self.conditions.setup()
        track_callers(srv)
        self._hook_writes()
        self._hook_access()
        self.limits.install()
        await srv.start()
        log.info("OPC UA server on %s (feed %s)", self.endpoint, self.feed_path)

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

    def _hook_access(self) -> None:
        """UserAccessLevel and UserExecutable as the reading session may act: read and
        write on a writable name, and the methods, for a writer; read only and no method
        for everyone else (asyncua answers the node's AccessLevel and Executable to every
        session)."""
        space = self.space

        async def post_read(event: ServerItemCallback, dispatcher: Any) -> None:
            results = event.response_params
            if not results:
                return
            user = event.user
            for k, rv in enumerate(event.request_params.NodesToRead):
                if rv.NodeId.NamespaceIndex != NS or not results[k].StatusCode.is_good():
                    continue
                if rv.AttributeId == ua.AttributeIds.UserExecutable:
                    may_run = self.methods.executable(rv.NodeId, user)
                    if may_run is not None:
                        results[k] = ua.DataValue(ua.Variant(may_run, ua.VariantType.Boolean))
                    continue
                if (rv.AttributeId != ua.AttributeIds.UserAccessLevel
                        or rv.NodeId not in space.all_vars):
                    continue
                i = space.by_node.get(rv.NodeId)
                may = (i is not None and space.names[i] in self.opc.writable
                       and user is not None and self.may_write(user))
                results[k] = ua.DataValue(ua.Variant(READ_WRITE if may else READ_ONLY,
                                                     ua.VariantType.Byte))
        self.server.iserver.callback_service.addListener(CallbackType.PostRead, post_read)

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
        except OutOfRange as exc:
            log.info("opcua write of %s refused: %s", name, exc)
            return ua.StatusCode(Status.BadOutOfRange)
        except (ValueError, TypeError, AttributeError):
            return ua.StatusCode(Status.BadTypeMismatch)
        ok, text, code = await self.ask("set", name, value, self.feed.side)
        if not ok:
            log.info("opcua write of %s refused by the controller: %s", name, text)
        return ua.StatusCode(getattr(Status, code, Status.BadInvalidState))

    async def ask(self, kind: str, *args: Any) -> tuple[bool, str, str]:
        """A request to the controller through the feed (``set``, ``call``, ``alarm``:
        runtime/controller/feed.py), waited for: (ok, text, OPC UA status name)."""
        try:
            return await self.feed.ask(kind, *args, timeout=WRITE_TIMEOUT_S)
        except TimeoutError:
            return False, "the controller did not answer in time", "BadTimeout"
        except (OSError, FeedLost):
            return False, "no connection to the controller", "BadNoCommunication"

    # -- the feed ----------------------------------------------------------------
    async def run(self) -> None:
        """Follow the feed until ``stop()``: reconnect forever; meanwhile watch for stale
        values and keep the limits."""
        watchers = [asyncio.create_task(self._watch_stale()),
                    asyncio.create_task(self.limits.housekeeping())]
        try:
            await self.feed.run()
        finally:
            for task in watchers:
                task.cancel()
            await asyncio.gather(*watchers, return_exceptions=True)

    def stop(self) -> None:
        """End ``run()``: the feed connection is closed (a read waiting on it ends)."""
        self.feed.stop()

    async def _lost(self) -> None:
        """The feed's connection ended: every value BadNoCommunication until it is back."""
        self.connected.clear()
        self._last_frame, self.stale = None, False
        # the next frame and status are states, not changes from these
        self._prev, self._prev_status = {}, None
        await self._all_bad(Status.BadNoCommunication)
        self._shown = []  # every value written again by the next frame

    async def _status(self) -> None:
        """The controller's status (with its alarm board) came: the conditions follow,
        and the drivers' and the controller's events (``_status_events``)."""
        await self.conditions.update(self.state.status.get("alarms") or [])
        await self._status_events()

    async def _alarm(self) -> None:
        """One change of an alarm came (the feed sends each, in order): its event."""
        change = self.state.alarm
        if change is not None:
            await self.conditions.change(change[1])

    async def _schema(self, schema: dict[str, Any]) -> None:
        self._last_frame = None  # no stale check while the names change
        names = [tuple(n) for n in schema["names"]]
        if names != self._names_built:  # names, types and roles: an online change
            await build_names(schema, self.space, lambda n: n in self.opc.writable,
                              self.server)
            self._names_built = names
            self._shown = []
            log.info("address space: %d plant names", len(names))
        self._last_frame = asyncio.get_running_loop().time()
        self.connected.set()

    async def _frame(self) -> None:
        """Every value of the frame, one batch, the frame's source timestamp. No await in
        here suspends (see the module docstring): a publish never splits the batch."""
        self._last_frame = asyncio.get_running_loop().time()
        if self.stale:
            self.stale = False
            log.warning("frames from the controller again: values good")
        ts = datetime.datetime.fromtimestamp(self.state.wall, datetime.UTC)
        await self._write_values(ts, None)
        self.frames += 1
        await self._derive_events(ts)

    async def _write_values(self, ts: datetime.datetime, status: int | None) -> None:
        """The last frame's values, with ``ts`` as their source timestamp; with their own
        status (Good, or BadOutOfRange: ``to_ua``), or all with ``status``."""
        st, space = self.state, self.space
        now = datetime.datetime.now(datetime.UTC)
        write = self.server.iserver.aspace.write_attribute_value
        value_attr = ua.AttributeIds.Value
        values, shown = st.values, self._shown
        if len(shown) != len(space.nodes):
            shown = self._shown = [_UNSHOWN] * len(space.nodes)
        for i, node_id in enumerate(space.nodes):
            raw, was = values[i], shown[i]
            if (status is None and was[1] is None and was[0] == raw
                    and type(was[0]) is type(raw)):
                continue  # as shown: no write, no notification, no time spent
            shown[i] = (raw, status)
            ptype = space.types[i]
            value, code = to_ua(ptype, raw)
            await write(node_id, value_attr, _dv(ptype, value, ts, now, status or code))
        c = st.status
        ctl: dict[str, Any] = {"scan": st.scan, "scans": st.scan + 1}
        if st.status_current:  # else none yet on this connection: those are not written
            lat = c.get("lateness_us") or {}
            ctl.update(state=c.get("state", ""), fault=c.get("fault") or "",
                       cycle=c.get("cycle_ms", 0.0), overruns=c.get("overruns", 0),
                       lateness_p50=lat.get("p50", 0.0), lateness_p99=lat.get("p99", 0.0),
                       lateness_max=lat.get("max", 0.0), uptime=float(c.get("uptime_s", 0)))
        good = status or Status.Good
        for key, value in ctl.items():
            ptype = space.all_vars[nid(f"controller.{key}")]
            await write(nid(f"controller.{key}"), value_attr,
                        _dv(ptype, value, ts, now, good))
        drivers = (c.get("drivers") or {}) if st.status_current else {}
        for dname, (health, reason, _ok) in drivers.items():
            if dname in space.drivers:
                await write(nid(f"driver.{dname}.health"), value_attr,
                            _dv("string", health, ts, now, good))
                await write(nid(f"driver.{dname}.fault"), value_attr,
                            _dv("string", reason, ts, now, good))

    async def _watch_stale(self) -> None:
        """Every sample: the controller wrote no image for ``stale_after_s`` (its own
        monotonic stamp in the shared image: this loop being busy never counts), or,
        without an image, no frame came for that long: every value BadOutOfService (with
        the last frame's source timestamp); the next frame makes them good."""
        loop = asyncio.get_running_loop()
        period = self.opc.sample_ns / 1e9
        bound = stale_after_s(self.opc.sample_ns)
        while True:
            await asyncio.sleep(period)
            age = self.feed.controller_age_s()
            if age is not None:
                if self.stale or self._last_frame is None or age <= bound:
                    continue
                if len(self.state.values) != len(self.space.nodes):
                    continue  # a schema without its first frame: nothing good shown yet
                await self._go_stale(age)
                continue
            last = self._last_frame
            if self.stale or last is None or loop.time() - last <= bound:
                continue
            # a frame the loop has read but not yet applied (the loop was busy) goes first
            for _ in range(3):
                await asyncio.sleep(0)
            last = self._last_frame
            if self.stale or last is None or loop.time() - last <= bound:
                continue
            if len(self.state.values) != len(self.space.nodes):
                continue  # a schema without its first frame: nothing good shown yet
            await self._go_stale(loop.time() - last)

    async def _go_stale(self, age: float) -> None:
        """Every value BadOutOfService, with the last frame's source timestamp."""
        self.stale = True
        log.warning("no frame from the controller for %.1f s (stopped, frozen, or stuck "
                    "in a scan): every value BadOutOfService until it sends again", age)
        await self._write_values(
            datetime.datetime.fromtimestamp(self.state.wall, datetime.UTC), STALE)

    async def _all_bad(self, code: int) -> None:
        dv = ua.DataValue(StatusCode=ua.StatusCode(code),
                          SourceTimestamp=datetime.datetime.now(datetime.UTC))
        write = self.server.iserver.aspace.write_attribute_value
        for node_id in self.space.all_vars:
            await write(node_id, ua.AttributeIds.Value, dv)

    # -- events ------------------------------------------------------------------
    async def _derive_events(self, ts: datetime.datetime) -> None:
        """Each frame: an instance's SFCError set or cleared (values of the frame)."""
        st, prev = self.state, self._prev
        now: dict[str, Any] = {}
        for name in self.space.instances:
            key = f"{name}.SFCError"
            if key in st.index:
                now[f"i:{name}"] = (st.get(key), st.get(f"{name}.SFCErrorStep")
                                    if f"{name}.SFCErrorStep" in st.index else "")
        self._prev = now
        if not prev:
            return  # the first frame after a (re)connection: a state, not a change
        await self._fire(prev, now, ts)

    async def _status_events(self) -> None:
        """Each status, in the order they came: a driver's fault or recovery, the
        controller's fault, halt or acknowledgement. Taken from every status, not only
        from the one a frame finds: statuses come on the socket and frames from the
        image, each at its own pace, and a fault and its recovery said between two
        frames made no event."""
        status = self.state.status
        now: dict[str, Any] = {
            f"d:{dname}": (health, reason)
            for dname, (health, reason, _ok) in (status.get("drivers") or {}).items()}
        now["controller"] = (status.get("state"), status.get("fault"))
        prev, self._prev_status = self._prev_status, now
        if prev is None:
            return  # the first status after a (re)connection: a state, not a change
        await self._fire(prev, now, datetime.datetime.now(datetime.UTC))

    async def _fire(self, prev: dict[str, Any], now: dict[str, Any],
                    ts: datetime.datetime) -> None:
        """An event for each key whose value changed from ``prev`` to ``now``."""
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
            return (f"{name}: SFCError {sfcerror_cause(new[1])}",
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


#: a plant variable's last write not known (none since the (re)connection or the schema):
#: its next value is written whatever it is
_UNSHOWN: tuple[Any, int | None] = (object(), None)
#: one StatusCode object per code a value may carry (a frame writes thousands)
_CODES: dict[int, ua.StatusCode] = {}


def _dv(ptype: str, value: Any, ts: datetime.datetime, now: datetime.datetime,
        code: int) -> ua.DataValue:
    """A value with its status; a Bad one without its value (Part 4, 7.7.1: its value
    is to be ignored, asyncua sets it null)."""
    sc = _CODES.get(code)
    if sc is None:
        sc = _CODES[code] = ua.StatusCode(code)
    if sc.is_bad():
        return ua.DataValue(StatusCode=sc, SourceTimestamp=ts, ServerTimestamp=now)
    return ua.DataValue(ua.Variant(value, TYPES[ptype][0]), StatusCode=sc,
                        SourceTimestamp=ts, ServerTimestamp=now)


async def serve(pdef: PlantDef, endpoint: str | None = None, feed: str | None = None,
                ready: Callable[[PlantServer], None] | None = None,
                stop: asyncio.Event | None = None) -> None:
    """Run the server until ``stop`` is set (or forever)."""
    ps = PlantServer(pdef, endpoint, feed)  # its certificate and key read: at once
    yield_cpu()
    await ps.start()
    task = asyncio.create_task(ps.run())
    if ready is not None:
        ready(ps)
    try:
        if stop is None:
            await task
        else:  # until stop, or the feed's end (a feed refused: feedclient.ForeignFeed)
            waiter = asyncio.ensure_future(stop.wait())
            await asyncio.wait({task, waiter}, return_when=asyncio.FIRST_COMPLETED)
            waiter.cancel()
            ps.stop()
            await task
    finally:
        await ps.server.stop()


def yield_cpu() -> None:
    """Lower this process's priority to SERVER_NICE (never raise it): a server swamped by
    clients slows itself, not the controller, also when started by hand."""
    try:
        now = os.nice(0)
        if now < SERVER_NICE:
            os.nice(SERVER_NICE - now)
            log.info("OPC UA server at niceness %d: the controller gets the CPU first",
                     SERVER_NICE)
    except OSError as exc:
        log.warning("OPC UA server: niceness not changed (%s)", exc)
