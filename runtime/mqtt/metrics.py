"""The Sparkplug metrics of a plant: which feed names are published, under which metric
names, types, aliases, on the edge node or on an instance's device.

Built from the feed's schema (``Layout.build``) and the ``mqtt:`` section: every name of a
group of ``publish:`` (by its role), every name listed, every ``writable:`` name (a DCMD
needs a metric born), and the node's own metrics. A metric's value is read from the last
frame (``FeedState``), from the controller's status that came with it, or from what the
edge node holds itself (bdSeq, command results, the buffer's drops).

Metric names (docs/mqtt.md): on a device (one per instance) ``Inputs/iGo``,
``Outputs/oLamp``, ``Memory/sN``, ``Flags/SFCError``, ``Steps/gsA/X``, ``Steps/gsA/T``,
``Temporaries/t``, ``System/FirstScan``, ``Command/Result``; on the node ``bdSeq``,
``Node Control/Rebirth``, ``Controller/state`` ..., ``Drivers/io/health``,
``Drivers/io/Inputs/I0``, ``Edge/buffer_dropped``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from runtime.controller.feed import FeedState
from runtime.language import ast as A
from runtime.language.iolist import Meaning
from runtime.language.model import MqttDef
from runtime.mqtt.payload import PLANT_TYPES, DataType

#: role of a feed name -> (its publish group, its folder on the device)
ROLE_GROUPS = {"input": ("inputs", "Inputs"), "output": ("outputs", "Outputs"),
               "memory": ("memory", "Memory"), "chart flag": ("flags", "Flags"),
               "temporary": ("temporaries", "Temporaries"),
               "system value": ("", "System")}
#: the device metric holding the result of the last command
COMMAND_RESULT = "Command/Result"
REBIRTH = "Node Control/Rebirth"
BDSEQ = "bdSeq"
BUFFER_DROPPED = "Edge/buffer_dropped"
#: what Controller/state says while the edge node has no feed from the controller
OFFLINE = "offline"

#: a metric's value from (the feed's state, the edge node's own values)
Getter = Callable[[FeedState, dict[str, Any]], Any]


@dataclass(slots=True)
class Metric:
    """One metric: its Sparkplug name, alias and type; where its value comes from; the
    device it belongs to ("" for the node); the plant name a DCMD writes (writable only)."""

    name: str
    alias: int
    datatype: DataType
    get: Getter
    device: str = ""
    unit: str | None = None
    #: published with the statistics only (every ``statistics``), not on every change
    statistic: bool = False
    #: the plant name it shows (a DCMD writes it when writable)
    plant: str | None = None
    writable: bool = False
    #: the plant type (TIME values are sent in ms, written in ns)
    ptype: A.Type | None = None
    #: in births only (bdSeq, Node Control/Rebirth), never reported as a change
    birth_only: bool = False
    #: the I/O list's engineering range (low, high) and description of its plant name
    limits: tuple[float, float] | None = None
    description: str = ""


@dataclass(slots=True)
class Layout:
    """Every metric of the edge node, node first, then each device's, aliases 1, 2, ..."""

    metrics: list[Metric] = field(default_factory=list)
    #: device -> its metrics' positions in ``metrics``
    devices: dict[str, list[int]] = field(default_factory=dict)
    node: list[int] = field(default_factory=list)
    #: (device, metric name) -> position; (device, alias) -> position
    by_name: dict[tuple[str, str], int] = field(default_factory=dict)
    by_alias: dict[tuple[str, int], int] = field(default_factory=dict)
    #: feed names listed in ``publish:`` that the plant does not have
    missing: list[str] = field(default_factory=list)

    def add(self, m: Metric) -> None:
        k = len(self.metrics)
        self.metrics.append(m)
        (self.devices.setdefault(m.device, []) if m.device else self.node).append(k)
        self.by_name[(m.device, m.name)] = k
        self.by_alias[(m.device, m.alias)] = k

    def signature(self, device: str) -> list[tuple[str, int, int]]:
        """What a host learns from a birth of ``device`` ("" the node): names, aliases,
        types. A change of it needs a new birth."""
        where = self.devices.get(device, []) if device else self.node
        return [(self.metrics[k].name, self.metrics[k].alias, self.metrics[k].datatype)
                for k in where]

    @classmethod
    def build(cls, schema: dict[str, Any], q: MqttDef,
              meaning: Callable[[str], Meaning] | None = None) -> Layout:
        """The metrics of ``schema`` (the feed's) as ``q`` publishes them; ``meaning``
        gives each plant name's unit, range and description (the plant's I/O list,
        ``IOList.meaning``); without it a TIME value's unit (ms) only."""
        lay = cls()
        groups = set(q.publish)
        listed = {w for w in q.publish if "." in w}
        writable = set(q.writable)
        alias = iter(range(1, 1 << 62))

        def add(name: str, datatype: DataType, get: Getter, **kw: Any) -> None:
            lay.add(Metric(name, next(alias), datatype, get, **kw))

        add(BDSEQ, DataType.INT64, _own(BDSEQ), birth_only=True)
        add(REBIRTH, DataType.BOOLEAN, lambda st, own: False, birth_only=True)
        # it grows only while nothing is published: the next births carry it
        add(BUFFER_DROPPED, DataType.INT64, _own(BUFFER_DROPPED), birth_only=True)
        if "controller" in groups:
            add("Controller/state", DataType.STRING, _status("state", OFFLINE))
            add("Controller/fault", DataType.STRING, _status("fault", ""))
            add("Controller/cycle", DataType.DOUBLE, _status("cycle_ms", 0.0), unit="ms")
            add("Controller/scan", DataType.INT64, lambda st, own: st.scan, statistic=True)
            for key in ("overruns", "skipped", "freezes"):
                add(f"Controller/{key}", DataType.INT64, _status(key, 0), statistic=True)
            for key in ("p50", "p99", "max"):
                add(f"Controller/lateness_{key}", DataType.DOUBLE, _lateness(key), unit="us",
                    statistic=True)
            add("Controller/uptime", DataType.DOUBLE, _status("uptime_s", 0.0), unit="s",
                statistic=True)
        drivers = [str(d) for d in schema.get("drivers", [])]
        if "drivers" in groups:
            for d in drivers:
                add(f"Drivers/{d}/health", DataType.STRING, _driver(d, 0))
                add(f"Drivers/{d}/fault", DataType.STRING, _driver(d, 1))
        names = [(str(n), A.Type(t), str(r)) for n, t, r in schema["names"]]
        present = {n for n, _t, _r in names}
        lay.missing = sorted(listed - present)
        instances = list(schema.get("instances", {}))
        device_names: dict[str, list[tuple[str, int, A.Type, str]]] = {i: [] for i in instances}
        for i, (text, ptype, role) in enumerate(names):
            head, _, rest = text.partition(".")
            metric, group = _metric_name(rest, role, head in device_names)
            if not (group in groups or text in listed or text in writable):
                continue
            if head in device_names:
                device_names[head].append((metric, i, ptype, text))
            elif head in drivers:
                add(f"Drivers/{head}/{metric}", PLANT_TYPES[ptype], _feed(i, ptype),
                    plant=text, ptype=ptype, **_meant(meaning, text, ptype))
        for inst in instances:
            for metric, i, ptype, text in device_names[inst]:
                add(metric, PLANT_TYPES[ptype], _feed(i, ptype), device=inst, plant=text,
                    writable=text in writable, ptype=ptype, **_meant(meaning, text, ptype))
            add(COMMAND_RESULT, DataType.STRING, _own(f"{COMMAND_RESULT}:{inst}"),
                device=inst)
        return lay


def _meant(meaning: Callable[[str], Meaning] | None, text: str,
           ptype: A.Type) -> dict[str, Any]:
    """A plant metric's unit (its symbol), range and description, as ``Metric`` fields."""
    m = meaning(text) if meaning is not None else Meaning()
    unit = m.unit.symbol if m.unit is not None else ("ms" if ptype is A.Type.TIME else None)
    return {"unit": unit, "limits": m.range, "description": m.description}


def _metric_name(rest: str, role: str, instance: bool) -> tuple[str, str]:
    """(metric name, publish group) of an instance's name ``rest`` or a driver's point."""
    if not instance:
        if role == "point in":
            return f"Inputs/{rest}", "points"
        if role == "point out":
            return f"Outputs/{rest}", "points"
        return rest, "drivers"  # DRIVER.ok
    if role in ("step", "step time"):
        step, _, xt = rest.rpartition(".")
        return f"Steps/{step}/{xt}", "steps" if role == "step" else "step_times"
    group, folder = ROLE_GROUPS.get(role, ("", "Other"))
    return f"{folder}/{rest}", group


def _feed(i: int, ptype: A.Type) -> Getter:
    if ptype is A.Type.TIME:
        return lambda st, own: st.values[i] / 1e6  # ns -> ms
    if ptype is A.Type.BOOL:
        return lambda st, own: bool(st.values[i])
    return lambda st, own: st.values[i]


def _own(key: str) -> Getter:
    return lambda st, own: own.get(key)


def _status(key: str, default: Any) -> Getter:
    def get(st: FeedState, own: dict[str, Any]) -> Any:
        if not own.get("feed") or not st.status_current:
            # no feed, or no status yet on this connection: the state says so, the
            # others keep the last status's values
            return OFFLINE if key == "state" else st.status.get(key, default) or default
        value = st.status.get(key, default)
        return default if value is None else value
    return get


def _lateness(key: str) -> Getter:
    return lambda st, own: float((st.status.get("lateness_us") or {}).get(key, 0.0))


def _driver(name: str, field_no: int) -> Getter:
    def get(st: FeedState, own: dict[str, Any]) -> Any:
        entry = (st.status.get("drivers") or {}).get(name)
        return "" if entry is None else str(entry[field_no] or "")
    return get
