"""``softplc mqtt PLANT``: the plant's Sparkplug B edge node on its MQTT broker, fed by the
controller's feed, in a process of its own (never in the scan's way).

- **Brokers.** ``mqtt: brokers:`` in order: a broker that cannot be reached, refuses the
  node, or drops it, is followed by the next one; after a whole round without a session
  the node waits (RECONNECT_MIN_S doubling to RECONNECT_MAX_S, each wait drawn between
  half and all of it, so that a fleet does not come back all at once). TLS (``mqtts://``)
  checks the broker's certificate and name against ``tls: ca`` (or the system's CAs) and
  shows ``tls: certificate`` when set; the password is read from ``password_file`` at each
  connection.
- **A session.** CONNECT (clean session) with the NDEATH of the next ``bdSeq`` as its Will
  (QoS 1); subscriptions to the node's NCMD, its devices' DCMD and, with ``primary_host``,
  the host's STATE (``spBv1.0/STATE/HOST``, JSON ``{"online": ..., "timestamp": ...}``,
  retained); then the births (runtime/mqtt/node.py), at once or once STATE says online. A
  STATE saying offline (newer than the last one seen in this session: each broker holds
  its own) ends the session: NDEATH published, DISCONNECT, the next broker. A STATE
  stamped more than STATE_AHEAD_MAX_MS ahead of this machine's clock is refused (taken,
  it would make every real one look older), and looked at again as the clock goes on.
  Stopping publishes the NDEATH, then disconnects.
- **Publishing** goes through one queue, in order. While more than REPORT_BACKLOG messages
  wait in it (the broker, or this process, does not keep up with the changes), a frame's
  report is skipped: the next report carries every change since the last one sent (values
  that came and went in between are not seen), so the rate of reports falls to what the
  link carries. A session whose queue passes OUTBOX_MAX messages is ended (NDEATH,
  DISCONNECT) and born again on the next one.
- **A broker that stalls.** Data messages go out at QoS 0: nothing acknowledges them. Each
  one's report is kept in the journal (runtime/mqtt/forward.py) until the broker answers
  a request sent after it (``_watch``, every PROBE_S while data goes out); a broker that
  does not answer in ``stall_s`` (the keepalive, from STALL_MIN_S to STALL_MAX_S) has
  stalled: the session ends, and whatever the broker was not seen to take goes back to
  the buffer, to be sent as history after the next births, as what the session ended
  before sending at all.
- **Commands.** A command with the retain flag is refused (a broker would hand it to every
  new session). NCMD: ``Node Control/Rebirth``, folded to one rebirth at most every
  REBIRTH_HOLD_S (runtime/mqtt/node.py). DCMD: writes of ``mqtt: writable:`` names,
  all checked before any is sent (runtime/mqtt/node.py), then applied by the controller
  between two scans (the feed's ``set``), at most MAX_PENDING_WRITES at a time (more are
  refused, busy). Every refusal, and every payload that is no command (undecodable, too
  large, too many metrics, wrong types), is one log line and, for a device, its
  ``Command/Result`` metric; the same line repeated is held back by the log's rate limit
  (runtime/controller/logsetup.py: 5 in 10 s, then a count).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import random
import ssl
from collections.abc import Callable
from typing import Any

import aiomqtt

from runtime.controller.aio import NO_TIMEOUT, within
from runtime.controller.feedclient import FeedClient, FeedLost
from runtime.errors import SoftplcError
from runtime.language.iolist import IOList
from runtime.language.model import MqttBroker, MqttDef, PlantDef
from runtime.mqtt.forward import Journal
from runtime.mqtt.node import CommandRefused, EdgeNode, Message, Write
from runtime.mqtt.payload import CommandError, decode_command

log = logging.getLogger(__name__)

#: why a command with the retain flag is refused
RETAINED = ("a retained command (a broker hands it to every new session: a command is "
            "never retained)")

#: waits between two rounds of the brokers, seconds (doubling, drawn in [half, all])
RECONNECT_MIN_S = 1.0
RECONNECT_MAX_S = 30.0
#: how long a CONNECT may take, seconds
CONNECT_TIMEOUT_S = 10.0
#: the NDEATH published before a clean disconnect: how long its PUBACK may take, seconds
DEATH_TIMEOUT_S = 2.0
#: messages waiting to be published beyond which a frame's report is skipped
REPORT_BACKLOG = 200
#: messages waiting to be published before the session is given up (broker too slow)
OUTBOX_MAX = 10_000
#: how long stopping may take before the process ends without its NDEATH, seconds (the
#: unit's TimeoutStopSec is 10 s)
STOP_TIMEOUT_S = 6.0
#: DCMD writes waiting for the controller's answer at once; more are refused (busy)
MAX_PENDING_WRITES = 32
#: a write the controller has not answered in this long is refused, seconds
WRITE_TIMEOUT_S = 3.0
#: a STATE whose timestamp is further ahead of this machine's clock is refused, ms
STATE_AHEAD_MAX_MS = 60_000
#: while data messages go out, the broker is asked to answer this often, seconds
PROBE_S = 0.5
#: a broker that has not answered in the keepalive, bounded by these, has stalled, seconds
STALL_MIN_S = 2.0
STALL_MAX_S = 5.0


class SessionEnded(SoftplcError):
    """A session ends on purpose: the primary host went offline, the publishing queue
    overflowed (the broker does not keep up), the broker stalled, the process stops."""


class BrokerStalled(SessionEnded):
    """The broker did not answer in time: its connection is given up."""


def tls_context(q: MqttDef) -> ssl.SSLContext:
    """The TLS context of the ``mqtts://`` brokers (OSError, ssl.SSLError if a file is
    missing or no certificate)."""
    ca = q.tls.ca if q.tls is not None else None
    ctx = ssl.create_default_context(cafile=ca)
    if q.tls is not None and q.tls.certificate is not None:
        ctx.load_cert_chain(q.tls.certificate, q.tls.private_key)
    return ctx


def read_password(path: str) -> str:
    """The first line of ``path`` (OSError if it cannot be read)."""
    with open(path, encoding="utf-8") as f:
        return f.readline().rstrip("\r\n")


class EdgeSession:
    """The edge node of ``pdef`` on its brokers, fed by the feed at ``feed_path``."""

    def __init__(self, pdef: PlantDef, feed_path: str | None = None) -> None:
        assert pdef.mqtt is not None
        self.q = q = pdef.mqtt
        self.feed = FeedClient(feed_path or q.feed, "mqtt", self._on_schema, self._on_frame,
                               self._on_lost, plant=pdef)
        self.node = EdgeNode(q, self.feed.state, meaning=IOList(pdef).meaning)
        self.tls = tls_context(q) if any(b.tls for b in q.brokers) else None
        if q.password_file is not None:
            read_password(q.password_file)  # at start: a missing file is an error now
        #: (session, message, its place in the journal or 0) to publish, in order
        self.outbox: asyncio.Queue[tuple[int, Message, int]] = asyncio.Queue()
        #: the session the queued messages belong to (stale ones are never sent)
        self.session_no = 0
        #: the reports of this session's data messages the broker was not seen to take
        self.journal = Journal()
        #: the journal's place of the last message handed to the connection, and of the
        #: last one the broker was seen to take
        self._handed = 0
        self._confirmed = 0
        self.host_online = q.primary_host is None
        #: the newest STATE timestamp of this session; a STATE refused as too far ahead
        #: of this machine's clock, looked at again as the clock goes on
        self._state_ts = -1
        self._state_ahead: bytes | None = None
        self._rebirth_timer: asyncio.TimerHandle | None = None
        self._broker = 0
        self._pending_writes = 0
        self._stop = asyncio.Event()
        self._client: aiomqtt.Client | None = None
        #: a session is up (tests, benchmarks)
        self.connected = asyncio.Event()
        #: counters: messages published, sessions, commands applied, commands refused,
        #: frames whose report was skipped (too many messages waiting)
        self.skipped = 0
        self.published = 0
        self.sessions = 0
        self.applied = 0
        self.refused = 0

    # -- the feed ----------------------------------------------------------------
    async def _on_schema(self, schema: dict[str, Any]) -> None:
        self.node.schema()

    async def _on_frame(self) -> None:
        if self.outbox.qsize() > REPORT_BACKLOG and not self.node.owes_births:
            # the broker (or this process) does not keep up: this frame's report is
            # skipped, the next one carries every change since the last one sent
            self.skipped += 1
            return
        self.send(self.node.frame())

    async def _on_lost(self) -> None:
        self.send(self.node.lost())

    def send(self, messages: list[Message]) -> None:
        for m in messages:
            place = self.journal.add(m.report) if m.report is not None else 0
            self.outbox.put_nowait((self.session_no, m, place))

    # -- sessions ----------------------------------------------------------------
    async def run(self) -> None:
        """Follow the feed and keep a session on a broker until ``stop()``."""
        await self.feed.run_beside(self._sessions())  # a feed refused ends it

    def stop(self) -> None:
        self._stop.set()

    async def _sessions(self) -> None:
        delay = RECONNECT_MIN_S
        failed = 0
        while not self._stop.is_set():
            # nothing to birth before the controller's first schema
            while self.node.layout is None and not self._stop.is_set():
                await self._wait(0.05)
            if self._stop.is_set():
                return
            broker = self.q.brokers[self._broker]
            up = False
            try:
                up = await self._session(broker)
            except SessionEnded as exc:
                up = True
                log.warning("mqtt: session on %s ended: %s", broker.url, exc)
            except (aiomqtt.MqttError, OSError, ssl.SSLError, ValueError) as exc:
                log.warning("mqtt: broker %s: %s", broker.url, exc or type(exc).__name__)
            finally:
                up = up or self.connected.is_set()  # a session that was up, then dropped
                self._client = None
                self.connected.clear()
                self._end_session()
            if self._stop.is_set():
                return
            self._broker = (self._broker + 1) % len(self.q.brokers)
            if up:
                delay, failed = RECONNECT_MIN_S, 0
                await self._wait(random.uniform(0.1, RECONNECT_MIN_S))
                continue
            failed += 1
            if failed % len(self.q.brokers) == 0:  # a whole round: wait
                await self._wait(random.uniform(delay / 2, delay))
                delay = min(RECONNECT_MAX_S, delay * 2)

    def _end_session(self) -> None:
        """What the session published and the broker was not seen to take goes back to
        the buffer (history after the next births); nothing more is sent for it."""
        lost = self.journal.take()
        if lost:
            log.info("mqtt: %d report(s) the broker was not seen to take: kept, to be sent "
                     "again as history", len(lost))
        self.node.session_lost()
        self.node.requeue(lost)
        self.session_no += 1
        self._handed = self._confirmed = self.journal.last
        if self._rebirth_timer is not None:
            self._rebirth_timer.cancel()
            self._rebirth_timer = None

    async def _session(self, broker: MqttBroker) -> bool:
        """One session on ``broker`` until it ends or ``stop()``; True if it was up."""
        q = self.q
        will = self.node.will()
        password = read_password(q.password_file) if q.password_file is not None else None
        client = aiomqtt.Client(
            broker.host, broker.port, identifier=q.client_id, username=q.username,
            password=password, will=aiomqtt.Will(will.topic, will.payload, will.qos,
                                                 will.retain),
            clean_session=True, keepalive=q.keepalive_ns // 1_000_000_000,
            timeout=CONNECT_TIMEOUT_S, tls_context=self.tls if broker.tls else None)
        async with client:
            self._client = client
            self.sessions += 1
            t = self.node.topics
            log.info("mqtt: connected to %s as %s (group %s, edge node %s, bdSeq %d)",
                     broker.url, q.client_id, q.group_id, q.edge_node_id, self.node.bdseq)
            subs = [(t.node("NCMD"), 1), (t.device("DCMD", "+"), 1)]
            if q.primary_host is not None:
                subs.append((t.state(q.primary_host), 1))
                self.host_online = False
                # each broker holds its own STATE: this session reads it afresh
                self._state_ts, self._state_ahead = -1, None
            await within(client.subscribe(subs, timeout=NO_TIMEOUT), CONNECT_TIMEOUT_S)
            self.connected.set()
            if self.host_online:
                self.send(self.node.start_publishing())
            elif q.primary_host is not None:
                log.info("mqtt: waiting for the primary host %s to be online",
                         q.primary_host)
            try:
                async with asyncio.TaskGroup() as tg:
                    tg.create_task(self._publisher(client, self.session_no))
                    tg.create_task(self._receiver(client))
                    tg.create_task(self._watch(client))
                    tg.create_task(self._until_stop())
            except BaseExceptionGroup as group:
                first = _first(group)
                if isinstance(first, SessionEnded):
                    # a clean DISCONNECT sends no Will: the NDEATH is published first
                    # (to a stalled broker without waiting: it reads it when it wakes)
                    await self._goodbye(client, wait=not isinstance(first, BrokerStalled))
                    if self._stop.is_set():
                        return True
                raise first from None
        return True

    async def _until_stop(self) -> None:
        await self._stop.wait()
        raise SessionEnded("stopping")

    async def _goodbye(self, client: aiomqtt.Client, wait: bool = True) -> None:
        """NDEATH published (a clean DISCONNECT sends no Will), then DISCONNECT. Its
        PUBACK confirms every message handed before it."""
        death = self.node.death()
        handed = self._handed
        if not wait:
            with contextlib.suppress(aiomqtt.MqttError, TimeoutError):
                await within(client.publish(death.topic, death.payload, qos=1,
                                            timeout=NO_TIMEOUT), 0.01)
            log.info("mqtt: NDEATH sent to a broker that does not answer (bdSeq %d)",
                     self.node.bdseq)
            return
        try:
            await within(client.publish(death.topic, death.payload, qos=1,
                                        timeout=NO_TIMEOUT), DEATH_TIMEOUT_S)
            log.info("mqtt: NDEATH published (bdSeq %d)", self.node.bdseq)
            self._confirm(handed)
        except TimeoutError:
            log.warning("mqtt: NDEATH not published: no PUBACK in %g s", DEATH_TIMEOUT_S)
        except aiomqtt.MqttError as exc:
            log.warning("mqtt: NDEATH not published: %s", exc)

    async def _publisher(self, client: aiomqtt.Client, no: int) -> None:
        while True:
            session, m, place = await self.outbox.get()
            if session != no:
                continue
            if self.outbox.qsize() > OUTBOX_MAX:
                raise SessionEnded(f"{self.outbox.qsize()} messages waiting: the broker does "
                                   "not keep up")
            await within(client.publish(m.topic, m.payload, qos=m.qos, retain=m.retain,
                                        timeout=NO_TIMEOUT), CONNECT_TIMEOUT_S)
            self.published += 1
            if place:
                self._handed = place

    def _confirm(self, upto: int) -> None:
        """The broker took every message handed up to journal place ``upto``."""
        if upto > self._confirmed:
            self._confirmed = upto
            self.journal.confirm(upto)

    @property
    def stall_s(self) -> float:
        """How long the broker may take to answer before it is seen as stalled, s."""
        return min(STALL_MAX_S, max(STALL_MIN_S, self.q.keepalive_ns / 1e9))

    async def _watch(self, client: aiomqtt.Client) -> None:
        """While data messages go out, every PROBE_S: the broker is asked for an answer
        (an UNSUBSCRIBE of a filter this node never subscribes to: no side effect, an
        UNSUBACK whatever the broker's rules). A broker reads a connection in order: its
        answer confirms every message handed before the request. No answer within
        ``stall_s``: the broker has stalled, the session ends (BrokerStalled). Also looks
        again at a STATE refused as too far ahead of this machine's clock."""
        probe = self.node.topics.node("NCMD") + "/softplc-probe"
        while True:
            await asyncio.sleep(PROBE_S)
            if self._state_ahead is not None:
                self._state(self._state_ahead, again=True)
            if self._handed <= self._confirmed:
                continue
            handed = self._handed
            try:
                await within(client.unsubscribe(probe, timeout=NO_TIMEOUT), self.stall_s)
            except TimeoutError:  # no answer in time
                raise BrokerStalled(f"the broker did not answer for {self.stall_s:g} s"
                                    ) from None
            self._confirm(handed)

    async def _wait(self, seconds: float) -> None:
        try:
            await within(self._stop.wait(), seconds)
        except TimeoutError:
            pass

    # -- what comes in -----------------------------------------------------------
    async def _receiver(self, client: aiomqtt.Client) -> None:
        t = self.node.topics
        ncmd, dcmd = t.node("NCMD"), t.node("DCMD") + "/"
        state = t.state(self.q.primary_host) if self.q.primary_host is not None else None
        async for message in client.messages:
            topic = message.topic.value
            payload = message.payload
            data = payload if isinstance(payload, bytes | bytearray) else str(payload).encode()
            if topic == state:
                self._state(bytes(data))
            elif topic == ncmd:
                if message.retain:
                    self.refused += 1
                    _warn(f"mqtt: NCMD refused: {RETAINED}")
                else:
                    self._node_command(bytes(data))
            elif topic.startswith(dcmd):
                if message.retain:
                    self._refuse(topic[len(dcmd):], RETAINED)
                else:
                    self._device_command(topic[len(dcmd):], bytes(data))

    def _state(self, data: bytes, again: bool = False) -> None:
        """A STATE of the primary host (``again``: one refused as too far ahead, looked
        at again)."""
        try:
            msg = json.loads(data)
            online, ts = msg["online"], msg["timestamp"]
            if (not isinstance(online, bool) or not isinstance(ts, int)
                    or isinstance(ts, bool)):
                raise TypeError("online must be a Boolean, timestamp an integer")
        except (ValueError, KeyError, TypeError, RecursionError) as exc:
            _warn(f"mqtt: STATE of {self.q.primary_host} ignored: not a Sparkplug 3.0 "
                  f"STATE ({exc})")
            return
        ahead = ts - int(self.node.clock() * 1000)
        if ahead > STATE_AHEAD_MAX_MS:
            # one such STATE, taken, would make every real one look older; the line's
            # template is fixed, so that the log's rate limit holds back a flood of them
            if not again:
                log.warning("mqtt: STATE of %s ignored: its timestamp %d is %s ahead of this "
                            "machine's clock (at most %d s; are both clocks set?)",
                            self.q.primary_host, ts, _ahead(ahead),
                            STATE_AHEAD_MAX_MS // 1000)
            self._state_ahead = data
            return
        self._state_ahead = None
        if ts < self._state_ts:
            return  # an older STATE than the last one seen
        self._state_ts = ts
        if online and not self.host_online:
            self.host_online = True
            log.info("mqtt: primary host %s online: births", self.q.primary_host)
            self.send(self.node.start_publishing())
        elif not online and self.host_online:
            self.host_online = False
            raise SessionEnded(f"the primary host {self.q.primary_host} went offline")

    def _node_command(self, data: bytes) -> None:
        try:
            self.send(self.node.node_command(decode_command(data)))
        except (CommandError, CommandRefused) as exc:
            self.refused += 1
            _warn(f"mqtt: NCMD refused: {exc}")
            return
        self._schedule_rebirth()

    def _schedule_rebirth(self) -> None:
        """The rebirths asked during the hold after births: one, at its end."""
        due = self.node.rebirth_due
        if due is not None and self._rebirth_timer is None:
            self._rebirth_timer = asyncio.get_running_loop().call_later(
                max(0.01, due - self.node.clock()), self._owed_rebirth)

    def _owed_rebirth(self) -> None:
        self._rebirth_timer = None
        self.send(self.node.owed_rebirth())
        self._schedule_rebirth()  # not due yet by the node's clock: a little later

    def _device_command(self, device: str, data: bytes) -> None:
        try:
            writes = self.node.device_command(device, decode_command(data))
            if self._pending_writes + len(writes) > MAX_PENDING_WRITES:
                raise CommandRefused(f"{device}: busy: {MAX_PENDING_WRITES} writes already "
                                     "wait for the controller")
        except (CommandError, CommandRefused) as exc:
            self._refuse(device, str(exc))
            return
        self._pending_writes += len(writes)
        asyncio.get_running_loop().create_task(self._apply(device, writes))

    def _refuse(self, device: str, text: str) -> None:
        self.refused += 1
        _warn(f"mqtt: DCMD to {device} refused: {text}")
        if self.node.layout is not None and device in self.node.layout.devices:
            self.node.command_result(device, f"refused: {text}")

    async def _apply(self, device: str, writes: list[Write]) -> None:
        """The writes of one DCMD through the feed, sent together (the controller applies
        them in one call between two scans)."""
        try:
            answers = await asyncio.gather(
                *(self.feed.set(w.plant, w.value, WRITE_TIMEOUT_S) for w in writes),
                return_exceptions=True)
        finally:
            self._pending_writes -= len(writes)
        texts, refused = [], []
        for w, a in zip(writes, answers, strict=True):
            if isinstance(a, TimeoutError):
                refused.append(f"{w.metric}: the controller did not answer in time")
            elif isinstance(a, FeedLost | OSError):
                refused.append(f"{w.metric}: the controller is offline")
            elif isinstance(a, BaseException):
                refused.append(f"{w.metric}: {type(a).__name__}: {a}")
            elif not a[0]:
                refused.append(f"{w.metric}: {a[1]}")
            else:
                texts.append(a[1])
        if refused:
            self._refuse(device, "; ".join(refused))
        else:
            self.applied += 1
            self.node.command_result(device, "ok: " + "; ".join(texts))


def _ahead(ms: int) -> str:
    """``ms`` as a person reads it: seconds, days or years."""
    s = ms / 1000
    if s < 86400 * 2:
        return f"{s:.0f} s"
    if s < 86400 * 730:
        return f"{s / 86400:.0f} days"
    return f"{s / (86400 * 365.25):.3g} years"


def _warn(text: str) -> None:
    """One line of a refusal, its whole text as the template: the log's rate limit
    (runtime/controller/logsetup.py) holds back repeats of the same line, not different
    refusals."""
    log.warning(text.replace("%", "%%"))


def _first(group: BaseExceptionGroup[Any]) -> BaseException:
    """The first exception of a task group's group (its tasks end on the first one)."""
    first: BaseException = group
    while isinstance(first, BaseExceptionGroup):
        first = first.exceptions[0]
    return first


async def serve(pdef: PlantDef, feed: str | None = None,
                ready: Callable[[EdgeSession], None] | None = None,
                stop: asyncio.Event | None = None) -> None:
    """Run the edge node until ``stop`` is set (or forever)."""
    es = EdgeSession(pdef, feed)
    task = asyncio.create_task(es.run())
    if ready is not None:
        ready(es)
    if stop is None:
        await task
        return
    stopping = asyncio.create_task(stop.wait())
    await asyncio.wait([task, stopping], return_when=asyncio.FIRST_COMPLETED)
    stopping.cancel()
    es.stop()
    try:
        await within(task, STOP_TIMEOUT_S)
    except TimeoutError:
        # the process ends anyway: without a clean DISCONNECT the broker sends the Will
        log.warning("mqtt: not stopped in %g s (NDEATH and DISCONNECT not done): leaving "
                    "the NDEATH to the Will", STOP_TIMEOUT_S)
