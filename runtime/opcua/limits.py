"""What OPC UA clients may hold of the server (``opcua: limits:``, docs/opcua.md "Limits"),
so that no client, nor all of them together, can wedge the server or take the controller's
CPU, and a client that vanished stops costing anything soon.

- **Sessions**: at most ``sessions`` at once (a session whose connection is gone counts until
  it is closed); one more is refused at CreateSession with BadTooManySessions. A client
  asking for a longer session timeout gets ``session_timeout``.
- **Abandoned sessions**: asyncua keeps a session with subscriptions alive after its
  connection is lost, so that its client may reconnect to it (Part 4, 6.7), for its whole
  timeout; here such a session is closed, with its subscriptions, after ``abandoned``
  without a request (looked for every HOUSEKEEPING_S).
- **Subscriptions**: at most ``subscriptions`` per session (BadTooManySubscriptions), each
  publishing at most once per ``sample`` (a shorter interval, 0 included, is revised up to
  it: a publish between two values of one frame would split the frame).
- **Publishing rates**: the publishes a second of one session's subscriptions (1000 /
  interval in ms, summed) stay within ``publish_rate``, those of all sessions within
  ``publish_rate_total``: a new subscription that would pass either gets a longer
  interval, up to what is left; when less than MIN_RATE is left it is refused
  (BadTooManySubscriptions). (ModifySubscription changes nothing in asyncua: it answers
  the current interval.)
- **Monitored items**: at most ``items`` per session and ``items_total`` in all sessions;
  the items of a request past either limit get BadTooManyMonitoredItems (those before it
  are created). A queue holds at most QUEUE_MAX notifications per item, EVENT_QUEUE_MAX
  per event item (the alarm changes a stalled server fires at once when it reads the feed
  again, every one an event a client must see); a subscription keeps at most UNACKED_MAX
  publish results its client has not acknowledged.
- **Diagnostics**: the standard ServerDiagnosticsSummary (under Server > ServerDiagnostics)
  counts the sessions and subscriptions, refused sessions and requests, and the abandoned
  sessions closed (SessionAbortCount); refreshed at each read of it and every
  HOUSEKEEPING_S.

asyncua (2.1) has server-wide caps of its own (``InternalServer.max_*``): they are set
from these; the per-session counts and the abandoned sessions are done here, around
asyncua's services (its ``create_session``, ``create_subscription``,
``create_monitored_items`` and ``modify_monitored_items``).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Iterable
from typing import Any

from asyncua import Server, ua
from asyncua.common.callback import CallbackType, ServerItemCallback
from asyncua.common.utils import ServiceError

from runtime.language.model import OpcuaLimits
from runtime.opcua.methods import peer_text

log = logging.getLogger(__name__)

#: how often abandoned sessions are looked for and the diagnostics refreshed, seconds
HOUSEKEEPING_S = 1.0
#: notifications a monitored item queues between two publishes (0 asked: this many)
QUEUE_MAX = 100
#: events an event monitored item queues between two publishes (0 asked: this many): the
#: feed sends each change of an alarm, and a server whose event loop stalled fires those
#: of the stall at once, before its next publish (seen: 120 in a 5 s stall)
EVENT_QUEUE_MAX = 1000
#: publish results a subscription keeps that its client has not acknowledged
UNACKED_MAX = 100
#: a connection that has not activated a session in this long is closed, seconds
#: (asyncua's default: a server starved of CPU, at niceness 10, may take that long)
ACTIVATION_S = 30.0
#: a subscription is refused rather than granted fewer publishes a second than this
MIN_RATE = 0.1
#: connections (activated or not) beyond ``sessions`` accepted at once, for clients that
#: connect, ask for the endpoints and leave
SPARE_CONNECTIONS = 10

_IDS = ua.ObjectIds
#: the ServerDiagnosticsSummary variable and its components kept here -> its field
_SUMMARY_NODE = _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary
_SUMMARY_FIELDS = {
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_CurrentSessionCount:
        "CurrentSessionCount",
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_CumulatedSessionCount:
        "CumulatedSessionCount",
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_RejectedSessionCount:
        "RejectedSessionCount",
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_SessionAbortCount:
        "SessionAbortCount",
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_CurrentSubscriptionCount:
        "CurrentSubscriptionCount",
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_CumulatedSubscriptionCount:
        "CumulatedSubscriptionCount",
    _IDS.Server_ServerDiagnostics_ServerDiagnosticsSummary_RejectedRequestsCount:
        "RejectedRequestsCount",
}
_SUMMARY_IDS = frozenset(ua.NodeId(n) for n in (_SUMMARY_NODE, *_SUMMARY_FIELDS))


class Limits:
    """The limits of one server, installed around asyncua's services (``install``, after
    ``await server.init()``); ``housekeeping()`` runs for the server's life."""

    def __init__(self, server: Server, limits: OpcuaLimits, sample_ns: int,
                 clock: Any = time.monotonic) -> None:
        self.server = server
        self.limits = limits
        self.least_interval_ms = sample_ns / 1e6
        self.clock = clock
        self.cumulated_sessions = 0
        self.cumulated_subscriptions = 0
        self.rejected_sessions = 0
        self.rejected_requests = 0
        self.aborted = 0

    # -- set-up ------------------------------------------------------------------
    def install(self) -> None:
        iserver = self.server.iserver
        lim = self.limits
        iserver.max_session_timeout_ms = lim.session_timeout_ns / 1e6
        iserver.max_subscriptions = lim.sessions * lim.subscriptions
        # asyncua's cap, for every item: the data items are held to QUEUE_MAX here
        iserver.max_monitored_item_queue_size = EVENT_QUEUE_MAX
        iserver.max_unacked_messages_per_subscription = UNACKED_MAX
        iserver.max_pending_activation_seconds = ACTIVATION_S
        iserver.max_connections = lim.sessions + SPARE_CONNECTIONS
        self._wrap_sessions()
        self._wrap_subscriptions()
        self._wrap_items()
        iserver.callback_service.addListener(CallbackType.PreRead, self._pre_read)

    def _wrap_sessions(self) -> None:
        iserver = self.server.iserver
        plain = iserver.create_session

        def create_session(name: str, *args: Any, external: bool = False,
                           **kwargs: Any) -> Any:
            if external:
                open_now = len(self._sessions())
                if open_now >= self.limits.sessions:
                    self.rejected_sessions += 1
                    log.warning("opcua: refused a session from %s: %d sessions open "
                                "(opcua limits: sessions)", peer_text(name), open_now)
                    raise ServiceError(ua.StatusCodes.BadTooManySessions)
                self.cumulated_sessions += 1
            return plain(name, *args, external=external, **kwargs)
        iserver.create_session = create_session

    def _wrap_subscriptions(self) -> None:
        service = self.server.iserver.subscription_service
        plain = service.create_subscription

        async def create(params: ua.CreateSubscriptionParameters, callback: Any,
                         session_id: ua.NodeId, *args: Any, **kwargs: Any
                         ) -> ua.CreateSubscriptionResult:
            lim = self.limits
            mine = total_rate = my_rate = 0.0
            for s in service.subscriptions.values():
                rate = _rate(s.data.RevisedPublishingInterval)
                total_rate += rate
                if s.session_id == session_id:
                    mine += 1
                    my_rate += rate
            left = min(lim.publish_rate - my_rate, lim.publish_rate_total - total_rate)
            if mine >= lim.subscriptions or left < MIN_RATE:
                self.rejected_requests += 1
                log.warning("opcua: refused a subscription of session %s: it has %d, "
                            "publishing %.1f times a second, all sessions %.1f (opcua "
                            "limits: subscriptions, publish_rate, publish_rate_total)",
                            session_id.to_string(), mine, my_rate, total_rate)
                raise ServiceError(ua.StatusCodes.BadTooManySubscriptions)
            # at least the sample (0 included: see the module), and within the rates left
            params.RequestedPublishingInterval = max(
                params.RequestedPublishingInterval, self.least_interval_ms, 1000.0 / left)
            result = await plain(params, callback, session_id, *args, **kwargs)
            self.cumulated_subscriptions += 1
            return result
        service.create_subscription = create

    def _wrap_items(self) -> None:
        service = self.server.iserver.subscription_service
        plain_create = service.create_monitored_items
        plain_modify = service.modify_monitored_items

        async def create(params: ua.CreateMonitoredItemsParameters
                         ) -> list[ua.MonitoredItemCreateResult]:
            sub = service.subscriptions.get(params.SubscriptionId)
            if sub is None:  # asyncua answers it (BadSubscriptionIdInvalid)
                return list(await plain_create(params))
            total = mine = 0
            for s in service.subscriptions.values():
                n = len(s.monitored_item_srv._monitored_items)  # noqa: SLF001 - no API
                total += n
                if s.session_id == sub.session_id:
                    mine += n
            room = max(0, min(self.limits.items - mine, self.limits.items_total - total))
            asked = list(params.ItemsToCreate)
            for item in asked:
                _clamp_queue(item.RequestedParameters,
                             item.ItemToMonitor.AttributeId == ua.AttributeIds.EventNotifier)
            params.ItemsToCreate = asked[:room]
            out = list(await plain_create(params)) if params.ItemsToCreate else []
            refused = len(asked) - room
            if refused > 0:
                self.rejected_requests += 1
                log.warning("opcua: refused %d monitored item(s) of session %s: %d held, "
                            "%d by all sessions (opcua limits: items %d per session, "
                            "items_total %d)", refused, sub.session_id.to_string(),
                            mine + room, total + room, self.limits.items,
                            self.limits.items_total)
                out += [ua.MonitoredItemCreateResult(
                    StatusCode=ua.StatusCode(ua.StatusCodes.BadTooManyMonitoredItems))
                        for _ in range(refused)]
            return out
        service.create_monitored_items = create

        def modify(params: ua.ModifyMonitoredItemsParameters
                   ) -> list[ua.MonitoredItemModifyResult]:
            # asyncua takes a modified queue size as asked (0: unbounded): bounded here
            sub = service.subscriptions.get(params.SubscriptionId)
            held = sub.monitored_item_srv._monitored_items if sub is not None else {}  # noqa: SLF001 - no API
            for item in params.ItemsToModify:
                mdata = held.get(item.MonitoredItemId)
                watched = getattr(mdata, "read_value_id", None)
                _clamp_queue(item.RequestedParameters, getattr(watched, "AttributeId", None)
                             == ua.AttributeIds.EventNotifier)
            return list(plain_modify(params))
        service.modify_monitored_items = modify

    # -- housekeeping ---------------------------------------------------------------
    def _sessions(self) -> list[Any]:
        """The clients' sessions not closed yet (asyncua's registry by token)."""
        return list(self.server.iserver._external_sessions.values())  # noqa: SLF001

    async def housekeeping(self) -> None:
        """Every HOUSEKEEPING_S until cancelled: close abandoned sessions, refresh the
        diagnostics."""
        while True:
            await asyncio.sleep(HOUSEKEEPING_S)
            try:
                await self.close_abandoned()
                await self.refresh_summary()
            except Exception:  # noqa: BLE001 - housekeeping never ends the server
                log.exception("opcua: housekeeping failed")

    async def close_abandoned(self) -> None:
        """Close every session with no connection that made no request for ``abandoned``
        (its subscriptions with it)."""
        bserver = self.server.bserver
        attached = {id(p.processor.session) for p in (bserver.clients if bserver else ())
                    if p.processor is not None}
        now = self.clock()
        quiet_s = self.limits.abandoned_ns / 1e9
        for session in self._sessions():
            idle = now - session._last_activity  # noqa: SLF001 - asyncua keeps it so
            if id(session) in attached or idle < quiet_s:
                continue
            subs = [i for i, s in self.server.iserver.subscription_service.subscriptions
                    .items() if s.session_id == session.session_id]
            await session.close_session(True)
            self.aborted += 1
            log.warning("opcua: closed the abandoned session %s (%s): its connection is gone "
                        "and it made no request for %.0f s; %d subscription(s) deleted",
                        session.session_id.to_string(), peer_text(session.name), idle, len(subs))

    def summary(self) -> ua.ServerDiagnosticsSummaryDataType:
        subs = self.server.iserver.subscription_service.subscriptions
        return ua.ServerDiagnosticsSummaryDataType(
            CurrentSessionCount=len(self._sessions()),
            CumulatedSessionCount=self.cumulated_sessions,
            RejectedSessionCount=self.rejected_sessions,
            SessionAbortCount=self.aborted,
            CurrentSubscriptionCount=len(subs),
            CumulatedSubscriptionCount=self.cumulated_subscriptions,
            RejectedRequestsCount=self.rejected_requests)

    async def refresh_summary(self) -> None:
        """Write the summary and the components kept here, and EnabledFlag true."""
        summary = self.summary()
        write = self.server.iserver.aspace.write_attribute_value
        value = ua.AttributeIds.Value
        await write(ua.NodeId(_SUMMARY_NODE), value, ua.DataValue(ua.Variant(
            summary, ua.VariantType.ExtensionObject)))
        for node, name in _SUMMARY_FIELDS.items():
            await write(ua.NodeId(node), value, ua.DataValue(ua.Variant(
                getattr(summary, name), ua.VariantType.UInt32)))
        await write(ua.NodeId(ua.ObjectIds.Server_ServerDiagnostics_EnabledFlag), value,
                    ua.DataValue(ua.Variant(True, ua.VariantType.Boolean)))

    async def _pre_read(self, event: ServerItemCallback, dispatcher: Any) -> None:
        """Before a read of the summary: refreshed, so a client reads the counts as they
        are (its own session and subscriptions included)."""
        params = event.request_params
        if any(r.NodeId in _SUMMARY_IDS for r in _nodes_to_read(params)):
            await self.refresh_summary()


def _rate(interval_ms: float) -> float:
    """Publishes a second of a subscription publishing every ``interval_ms``."""
    return 1000.0 / interval_ms if interval_ms > 0 else math.inf


def _nodes_to_read(params: Any) -> Iterable[ua.ReadValueId]:
    return getattr(params, "NodesToRead", None) or ()


def _clamp_queue(p: ua.MonitoringParameters, events: bool) -> None:
    """A queue size asked (0: the largest) held to QUEUE_MAX, EVENT_QUEUE_MAX for
    ``events`` (an event item)."""
    cap = EVENT_QUEUE_MAX if events else QUEUE_MAX
    if not 0 < p.QueueSize <= cap:
        p.QueueSize = cap
