"""The Sparkplug B edge node of a plant, without the network: what it publishes when, its
sequence numbers, its store-and-forward buffer, and what a command asks of the plant.

The MQTT session (runtime/mqtt/session.py) and the feed (runtime/controller/feedclient.py)
call it; every method returns the messages to publish, in order. Nothing here waits.

- **Births.** ``birth()`` when a session may publish (connected, and the primary host
  online when one is configured): NBIRTH (``seq`` 0, ``bdSeq`` of the session's Will, every
  node metric), then a DBIRTH per instance while the controller's feed is up, then the
  buffered changes. An NCMD ``Node Control/Rebirth`` asks for the same again, at most once
  in REBIRTH_HOLD_S after births: the requests that come sooner are folded into one
  rebirth at the hold's end (``owed_rebirth``, when ``rebirth_due`` says).
- **Report by exception.** ``frame()`` at most every ``sample``: the metrics whose value
  changed since they were last sent, one NDATA and one DDATA per device that has some,
  each value stamped with the time of the scan that produced it; the controller's
  statistics only every ``statistics``.
- **Devices die and come back with the feed.** The feed lost (the controller stopped or
  restarting): a DDEATH per device and ``Controller/state`` ``offline``. The feed back: a
  DBIRTH per device with its values; a schema whose node metrics changed (an online
  change that added a driver): a whole rebirth; a device whose metrics changed: DDEATH,
  DBIRTH; an instance gone: DDEATH.
- **Store and forward.** Not publishing (no broker, or the primary host offline): each
  report's changes are kept (``Buffer``), at most ``buffer`` metric values, the oldest
  reports dropped first (counted in ``Edge/buffer_dropped``); after the next births they
  are published as DDATA/NDATA with ``is_historical``, each value with its own timestamp,
  a device's values in order, HISTORY_CHUNK to a message (runtime/mqtt/forward.py). Each
  data message carries its report: what the broker was not seen to take before the
  session ended comes back (``requeue``) and goes out as history too.
- ``seq`` counts every message of a session but the NDEATH, 0 to 255 and round again;
  ``bdSeq`` counts the sessions (each CONNECT's Will), 0 to 255, from 0 at start.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from runtime.controller.feed import FeedState
from runtime.errors import SoftplcError
from runtime.language import ast as A
from runtime.language.iolist import Meaning
from runtime.language.model import MqttDef
from runtime.mqtt.forward import Buffer, Report
from runtime.mqtt.metrics import (
    BDSEQ,
    BUFFER_DROPPED,
    COMMAND_RESULT,
    REBIRTH,
    Layout,
    Metric,
)
from runtime.mqtt.payload import NAMESPACE, Command, DataType, Value, encode

log = logging.getLogger(__name__)

#: buffered values forwarded in one message (a device's history, in order)
HISTORY_CHUNK = 500
#: an NCMD rebirth is done at most once in this long after a birth; the requests that
#: come meanwhile are folded into one rebirth at its end, seconds
REBIRTH_HOLD_S = 1.0


@dataclass(frozen=True, slots=True)
class Message:
    """One MQTT publication; a data message (NDATA, DDATA) carries the changes it reports
    (``report``), to be sent again as history if the broker may not have taken it."""

    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False
    report: Report | None = None


@dataclass(frozen=True, slots=True)
class Topics:
    """The topics of one edge node (``spBv1.0/GROUP/KIND/EDGE[/DEVICE]``)."""

    group: str
    edge: str

    def node(self, kind: str) -> str:
        return f"{NAMESPACE}/{self.group}/{kind}/{self.edge}"

    def device(self, kind: str, device: str) -> str:
        return f"{NAMESPACE}/{self.group}/{kind}/{self.edge}/{device}"

    @staticmethod
    def state(host: str) -> str:
        return f"{NAMESPACE}/STATE/{host}"


@dataclass(frozen=True, slots=True)
class Write:
    """A DCMD's write of one plant name, in the name's plant type (TIME in ns)."""

    metric: str
    plant: str
    value: Any


class CommandRefused(SoftplcError, ValueError):
    """A command that changes nothing; the message says why (logged and published).

    For example: a DCMD to ``Outputs/oLamp`` (not writable), a String for a Boolean."""


class EdgeNode:
    """The edge node's state and what it publishes (see the module docstring)."""

    def __init__(self, q: MqttDef, state: FeedState,
                 clock: Callable[[], float] = time.time,
                 meaning: Callable[[str], Meaning] | None = None) -> None:
        """``meaning``: a plant name's unit, range and description (the plant's I/O list,
        read at the edge node's start), given in the births."""
        self.q = q
        self.state = state
        self.clock = clock
        self.meaning = meaning
        self.topics = Topics(q.group_id, q.edge_node_id)
        self.layout: Layout | None = None
        #: the values last sent (or birthed), by metric position
        self.sent: list[Any] = []
        #: the edge node's own values (bdSeq, command results, the buffer's drops, feed up)
        self.own: dict[str, Any] = {BDSEQ: -1, BUFFER_DROPPED: 0, "feed": False}
        self.buffer = Buffer(q.buffer)
        #: the session may publish (connected, the primary host online if one is configured)
        self.publishing = False
        #: births done in this session: reports are published, not buffered
        self.online = False
        #: devices born in this session
        self.born: set[str] = set()
        #: a schema came and its frame has not yet: births and reports wait for values
        self._fresh_schema = False
        #: the layout the host knows (the last births'), to see what a new schema changes
        self._born_layout: Layout | None = None
        self._seq = 0
        self._last_scan = -(1 << 62)
        self._stats_due = 0.0
        self._every = max(1, q.sample_ns)  # ns between reports, compared on scan time
        self._commands = 0
        #: the clock's time of the last births; NCMD rebirths asked since and not done yet
        self._born_at = float("-inf")
        self._rebirths_owed = 0

    # -- the session ------------------------------------------------------------------
    @property
    def bdseq(self) -> int:
        return int(self.own[BDSEQ])

    def will(self) -> Message:
        """The next session's Will: an NDEATH with the next ``bdSeq`` (call once per
        CONNECT)."""
        self.own[BDSEQ] = (self.bdseq + 1) % 256
        return self.death()

    def death(self) -> Message:
        """The NDEATH of the current session (the Will, or published before a clean
        disconnect)."""
        now = self._ms()
        payload = encode(now, [Value(0, DataType.INT64, self.bdseq, now, name=BDSEQ)], None)
        return Message(self.topics.node("NDEATH"), payload, qos=1)

    def start_publishing(self) -> list[Message]:
        """The session may publish: the births now, or with the first frame when the node
        has no values yet."""
        self.publishing = True
        return self.birth()

    def session_lost(self) -> None:
        """The MQTT session ended: nothing is published until the next births."""
        self.publishing = False
        self.online = False
        self.born.clear()
        self._rebirths_owed = 0  # the next session births anyway

    @property
    def owes_births(self) -> bool:
        """A schema came whose first frame has not: that frame must not be skipped."""
        return self._fresh_schema

    def ready(self) -> bool:
        """Has the node what a birth needs (a layout and its values)?"""
        return self.layout is not None and not self._fresh_schema

    def birth(self) -> list[Message]:
        """NBIRTH, a DBIRTH per device (feed up), then the buffered reports (historical)."""
        lay = self.layout
        if lay is None or self._fresh_schema:
            return []
        self.online = True
        self._seq = 0
        self.born.clear()
        self._born_at = self.clock()
        self._rebirths_owed = 0  # these births answer them
        now = self._ms()
        self._stats_due = now + self.q.statistics_ns / 1e6  # the births carry them
        out = [self._birth("", "NBIRTH", now)]
        if self.own["feed"]:
            out += [self._birth(d, "DBIRTH", now) for d in lay.devices]
        self._born_layout = lay
        out += self._forward()
        return out

    # -- the feed -----------------------------------------------------------------
    def schema(self) -> None:
        """A schema came (a connection, or an online change): the new layout; births and
        reports wait for its first frame."""
        old = self.layout
        was = ({(m.device, m.name): self.sent[k] for k, m in enumerate(old.metrics)}
               if old is not None else {})
        self.layout = Layout.build(self.state.schema, self.q, self.meaning)
        for name in self.layout.missing:
            log.warning("mqtt publish: %s is not a name of the running plant: not published",
                        name)
        # what the host holds of the metrics that stay (an online change): only real
        # changes are reported after it
        self.sent = [was.get((m.device, m.name)) for m in self.layout.metrics]
        self.own["feed"] = True
        self._fresh_schema = True

    def frame(self) -> list[Message]:
        """A frame came: births owed by a new schema, or this report's changes."""
        lay = self.layout
        if lay is None:
            return []
        st = self.state
        if self._fresh_schema:
            self._fresh_schema = False
            self._last_scan = st.scan
            return self._after_schema()
        cycle_ns = float(st.schema.get("cycle_ms", 10.0)) * 1e6
        if (st.scan - self._last_scan) * cycle_ns < self._every - cycle_ns / 2:
            return []
        self._last_scan = st.scan
        return self.report(round(st.wall * 1000))

    def lost(self) -> list[Message]:
        """The feed's connection ended: every device dies, Controller/state says offline."""
        self.own["feed"] = False
        self._fresh_schema = False
        out: list[Message] = []
        if self.online:
            now = self._ms()
            for d in list(self.born):
                out.append(self._device_death(d, now))
        out += self.report(self._ms(), node_only=True)
        return out

    def _after_schema(self) -> list[Message]:
        """What the first frame of a schema owes the host (see the module docstring)."""
        lay, old = self.layout, self._born_layout
        assert lay is not None
        if not self.online:
            if self.publishing:  # connected while the feed had no values yet
                return self.birth()
            self._prime()
            return []
        now = self._ms()
        if old is None or lay.signature("") != old.signature(""):
            out = [self._device_death(d, now) for d in sorted(self.born) if d not in
                   lay.devices]
            return out + self.birth()
        out = []
        for d in sorted(self.born):
            if d not in lay.devices or lay.signature(d) != old.signature(d):
                out.append(self._device_death(d, now))
        for d in lay.devices:
            if d not in self.born:
                out.append(self._birth(d, "DBIRTH", now))
        self._born_layout = lay
        return out + self._node_changes(now)

    def _prime(self) -> None:
        """Not publishing, a new layout: its values as they are now count as sent (the
        next births carry them)."""
        assert self.layout is not None
        st, own = self.state, self.own
        self.sent = [m.get(st, own) for m in self.layout.metrics]

    # -- reports ------------------------------------------------------------------
    def report(self, now: int, node_only: bool = False) -> list[Message]:
        """The changes since the last report: published, or kept in the buffer."""
        lay = self.layout
        if lay is None:
            return []
        st, own, sent = self.state, self.own, self.sent
        stats = now >= self._stats_due
        if stats:
            self._stats_due = now + self.q.statistics_ns / 1e6
        feed = bool(own["feed"])
        changes: dict[str, list[int]] = {}
        for k, m in enumerate(lay.metrics):
            if m.device and (node_only or not feed):
                continue
            if (m.statistic and not stats) or m.birth_only:
                continue
            v = m.get(st, own)
            old = sent[k]
            if v != old or type(v) is not type(old):
                sent[k] = v
                changes.setdefault(m.device, []).append(k)
        if not changes:
            return []
        times = self._command_times(changes)
        ms = lay.metrics
        if not self.online:
            self.buffer.add(Report(now, [(ms[k].device, ms[k].name, ms[k].datatype, sent[k],
                                          times.get(k, now))
                                         for ks in changes.values() for k in ks]))
            self.own[BUFFER_DROPPED] = self.buffer.dropped
            return []
        out = []
        for device, ks in changes.items():
            if device and device not in self.born:
                continue
            values = [Value(ms[k].alias, ms[k].datatype, sent[k], times.get(k, now))
                      for k in ks]
            topic = (self.topics.device("DDATA", device) if device
                     else self.topics.node("NDATA"))
            kept = Report(now, [(device, ms[k].name, v.datatype, v.value, v.timestamp)
                                for k, v in zip(ks, values, strict=True)])
            out.append(Message(topic, encode(now, values, self._next_seq()), report=kept))
        return out

    def requeue(self, reports: list[Report]) -> None:
        """The session ended before the broker was seen to take ``reports``: they go back
        to the front of the buffer, to be sent as history after the next births."""
        if reports:
            self.buffer.add_front(reports)
            self.own[BUFFER_DROPPED] = self.buffer.dropped

    def _node_changes(self, now: int) -> list[Message]:
        return self.report(now, node_only=True)

    def _command_times(self, changes: dict[str, list[int]]) -> dict[int, int]:
        """Command results carry their own time (not the frame's)."""
        assert self.layout is not None
        out = {}
        for ks in changes.values():
            for k in ks:
                m = self.layout.metrics[k]
                if m.name == COMMAND_RESULT:
                    out[k] = int(self.own.get(f"{COMMAND_RESULT}:{m.device}:t", 0))
        return out

    def _forward(self) -> list[Message]:
        """The buffered reports, historical, after the births: per device (and the node),
        in order, each value with its own scan's time, HISTORY_CHUNK values a message."""
        lay = self.layout
        assert lay is not None
        per: dict[str, list[tuple[Value, tuple[str, str, DataType, Any, int]]]] = {}
        for rep in self.buffer.take():
            for change in rep.changes:
                device, name, datatype, value, at = change
                k = lay.by_name.get((device, name))
                if k is None or lay.metrics[k].datatype != datatype or (
                        device and device not in self.born):
                    continue  # a metric gone or changed meanwhile (an online change)
                per.setdefault(device, []).append(
                    (Value(lay.metrics[k].alias, datatype, value, at, historical=True),
                     change))
        out = []
        for device, values in per.items():
            topic = (self.topics.device("DDATA", device) if device
                     else self.topics.node("NDATA"))
            for start in range(0, len(values), HISTORY_CHUNK):
                chunk = values[start:start + HISTORY_CHUNK]
                at = chunk[-1][0].timestamp
                out.append(Message(topic, encode(at, [v for v, _c in chunk],
                                                 self._next_seq()),
                                   report=Report(at, [c for _v, c in chunk])))
        kept = sum(len(v) for v in per.values())
        if kept:
            log.info("mqtt: %d buffered value(s) forwarded as history", kept)
        return out

    # -- births and deaths --------------------------------------------------------
    def _birth(self, device: str, kind: str, now: int) -> Message:
        lay = self.layout
        assert lay is not None
        st, own, sent = self.state, self.own, self.sent
        where = lay.devices.get(device, []) if device else lay.node
        values = []
        for k in where:
            m = lay.metrics[k]
            v = m.get(st, own)
            sent[k] = v
            values.append(Value(m.alias, m.datatype, v, now, name=m.name, unit=m.unit,
                                limits=m.limits, description=m.description))
        if device:
            self.born.add(device)
            topic = self.topics.device(kind, device)
        else:
            topic = self.topics.node(kind)
        if kind == "NBIRTH":
            self._seq = 0
        return Message(topic, encode(now, values, self._next_seq()))

    def _device_death(self, device: str, now: int) -> Message:
        self.born.discard(device)
        return Message(self.topics.device("DDEATH", device),
                       encode(now, [], self._next_seq()))

    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) % 256
        return seq

    def _ms(self) -> int:
        return int(self.clock() * 1000)

    # -- commands -----------------------------------------------------------------
    def node_command(self, commands: list[Command]) -> list[Message]:
        """An NCMD: ``Node Control/Rebirth`` true is the only one; CommandRefused else."""
        lay = self.layout
        for c in commands:
            name = c.name
            if name is None and lay is not None:
                k = lay.by_alias.get(("", c.alias or 0))
                name = lay.metrics[k].name if k is not None else None
            if name != REBIRTH:
                raise CommandRefused(f"{name or f'alias {c.alias}'}: not a node command "
                                     f"(the only one is {REBIRTH})")
            if c.value is not True:
                raise CommandRefused(f"{REBIRTH}: expected the Boolean true, found "
                                     f"{c.value!r}")
        if not self.online:
            return []
        if self.clock() < self._born_at + REBIRTH_HOLD_S:
            self._rebirths_owed += 1  # folded into the rebirth at the hold's end
            return []
        log.info("mqtt: rebirth asked by an NCMD")
        return self.birth()

    @property
    def rebirth_due(self) -> float | None:
        """When the folded NCMD rebirths are owed (the clock's time), or None."""
        return self._born_at + REBIRTH_HOLD_S if self._rebirths_owed else None

    def owed_rebirth(self) -> list[Message]:
        """The rebirth the requests folded during the hold asked for, once it is over."""
        due = self.rebirth_due
        if not self.online:
            self._rebirths_owed = 0  # the next births answer them
            return []
        if due is None or self.clock() < due:
            return []
        log.info("mqtt: rebirth asked by %d NCMD(s) within %g s of the last births: one "
                 "rebirth for them all", self._rebirths_owed, REBIRTH_HOLD_S)
        return self.birth()

    def device_command(self, device: str, commands: list[Command]) -> list[Write]:
        """A DCMD to ``device``: the writes it asks for, every one checked first (all or
        nothing); CommandRefused says why not."""
        lay = self.layout
        if lay is None or device not in lay.devices:
            raise CommandRefused(f"no device '{device}' on this edge node")
        if not self.own["feed"]:
            raise CommandRefused(f"{device}: the controller is offline")
        out: list[Write] = []
        for c in commands:
            k = (lay.by_name.get((device, c.name)) if c.name is not None
                 else lay.by_alias.get((device, c.alias or 0)))
            if k is None:
                raise CommandRefused(f"{device}: no metric "
                                     f"{c.name if c.name is not None else f'alias {c.alias}'}")
            m = lay.metrics[k]
            if not m.writable or m.plant is None or m.ptype is None:
                raise CommandRefused(f"{device}: {m.name} is not writable (mqtt: writable)")
            out.append(Write(m.name, m.plant, _plant_value(m, c.value)))
        return out

    def command_result(self, device: str, text: str) -> None:
        """The result of a command to ``device``, published with the next report."""
        self._commands += 1
        self.own[f"{COMMAND_RESULT}:{device}"] = f"#{self._commands} {text}"
        self.own[f"{COMMAND_RESULT}:{device}:t"] = self._ms()


def _plant_value(m: Metric, value: Any) -> Any:
    """A command's value for metric ``m`` in its plant type; CommandRefused if it is of
    another type."""
    t = m.ptype
    ok = {A.Type.BOOL: isinstance(value, bool),
          A.Type.INT: isinstance(value, int) and not isinstance(value, bool),
          A.Type.REAL: isinstance(value, int | float) and not isinstance(value, bool),
          A.Type.TIME: isinstance(value, int | float) and not isinstance(value, bool),
          A.Type.STRING: isinstance(value, str)}.get(t, False) if t is not None else False
    if not ok:
        raise CommandRefused(f"{m.name}: expected a {m.datatype.name.title()} value, found "
                             f"{type(value).__name__} {value!r}"[:200])
    if t is A.Type.TIME:
        return round(value * 1e6)  # ms -> ns
    if t is A.Type.REAL:
        return float(value)
    return value
