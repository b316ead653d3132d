"""The Sparkplug B payload: its protobuf schema, its data types, and what this edge node
encodes (births, data, deaths) and decodes (commands, with limits).

The schema is the Sparkplug 3.0 specification's (``org.eclipse.tahu.protobuf.Payload``,
proto2): the field numbers and types of Payload, Metric, PropertySet and PropertyValue are
declared here as a protobuf descriptor, and the ``protobuf`` runtime (its C ``upb`` core
where it has a wheel, pure Python elsewhere) encodes and decodes them. No code generated
from the specification's ``sparkplug_b.proto`` is in this repository. The parts this node
never sends nor reads (DataSet, Template, MetaData, extensions) are left out: in a command
they are unknown fields, and a metric whose value is one of them has no value we accept.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError, Message

from runtime.errors import SoftplcError
from runtime.language import ast as A

#: the Sparkplug B topic namespace
NAMESPACE = "spBv1.0"
#: a command (NCMD, DCMD) larger than this is refused unread, bytes
COMMAND_MAX_BYTES = 65536
#: a command with more metrics than this is refused whole
COMMAND_MAX_METRICS = 64
#: the longest text value a command may carry, characters
COMMAND_MAX_TEXT = 1024


class DataType(enum.IntEnum):
    """Sparkplug B data types (the ones this node uses, and what a command may carry)."""

    UNKNOWN = 0
    INT8 = 1
    INT16 = 2
    INT32 = 3
    INT64 = 4
    UINT8 = 5
    UINT16 = 6
    UINT32 = 7
    UINT64 = 8
    FLOAT = 9
    DOUBLE = 10
    BOOLEAN = 11
    STRING = 12
    DATETIME = 13
    TEXT = 14


#: a plant type's Sparkplug type (TIME: Double, milliseconds, as OPC UA's Duration)
PLANT_TYPES = {A.Type.BOOL: DataType.BOOLEAN, A.Type.INT: DataType.INT64,
               A.Type.REAL: DataType.DOUBLE, A.Type.TIME: DataType.DOUBLE,
               A.Type.STRING: DataType.STRING}

_F = descriptor_pb2.FieldDescriptorProto
_OPT, _REP = _F.LABEL_OPTIONAL, _F.LABEL_REPEATED
_VALUE_FIELDS = (("int_value", _F.TYPE_UINT32), ("long_value", _F.TYPE_UINT64),
                 ("float_value", _F.TYPE_FLOAT), ("double_value", _F.TYPE_DOUBLE),
                 ("boolean_value", _F.TYPE_BOOL), ("string_value", _F.TYPE_STRING))


def _message(parent: Any, name: str,
             fields: Iterable[tuple[str, int, Any, Any, str | None]]) -> Any:
    """A nested message of ``parent``: fields (name, number, type, label, type name)."""
    msg = parent.nested_type.add() if hasattr(parent, "nested_type") else parent.message_type.add()
    msg.name = name
    for fname, number, ftype, label, type_name in fields:
        f = msg.field.add(name=fname, number=number, type=ftype, label=label)
        if type_name is not None:
            f.type_name = type_name
    return msg


def _value_oneof(msg: Any, first: int, extra: tuple[tuple[str, Any], ...] = ()) -> None:
    """The ``value`` oneof of ``msg`` from field number ``first`` on."""
    msg.oneof_decl.add(name="value")
    for k, (fname, ftype) in enumerate((*_VALUE_FIELDS, *extra)):
        msg.field.add(name=fname, number=first + k, type=ftype, label=_OPT, oneof_index=0)


def _schema() -> tuple[type[Message], type[Message]]:
    """The Payload and Payload.Metric classes, from a descriptor in a pool of their own."""
    fd = descriptor_pb2.FileDescriptorProto(name="softplc_sparkplug_b.proto",
                                            package="softplc.sparkplug", syntax="proto2")
    pkg = ".softplc.sparkplug.Payload"
    payload = _message(fd, "Payload", [
        ("timestamp", 1, _F.TYPE_UINT64, _OPT, None),
        ("metrics", 2, _F.TYPE_MESSAGE, _REP, f"{pkg}.Metric"),
        ("seq", 3, _F.TYPE_UINT64, _OPT, None),
        ("uuid", 4, _F.TYPE_STRING, _OPT, None),
        ("body", 5, _F.TYPE_BYTES, _OPT, None)])
    prop_value = _message(payload, "PropertyValue", [
        ("type", 1, _F.TYPE_UINT32, _OPT, None), ("is_null", 2, _F.TYPE_BOOL, _OPT, None)])
    _value_oneof(prop_value, 3)
    _message(payload, "PropertySet", [
        ("keys", 1, _F.TYPE_STRING, _REP, None),
        ("values", 2, _F.TYPE_MESSAGE, _REP, f"{pkg}.PropertyValue")])
    metric = _message(payload, "Metric", [
        ("name", 1, _F.TYPE_STRING, _OPT, None), ("alias", 2, _F.TYPE_UINT64, _OPT, None),
        ("timestamp", 3, _F.TYPE_UINT64, _OPT, None),
        ("datatype", 4, _F.TYPE_UINT32, _OPT, None),
        ("is_historical", 5, _F.TYPE_BOOL, _OPT, None),
        ("is_transient", 6, _F.TYPE_BOOL, _OPT, None),
        ("is_null", 7, _F.TYPE_BOOL, _OPT, None),
        ("properties", 9, _F.TYPE_MESSAGE, _OPT, f"{pkg}.PropertySet")])
    _value_oneof(metric, 10, (("bytes_value", _F.TYPE_BYTES),))
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    return (message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{pkg[1:]}")),
            message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{pkg[1:]}.Metric")))


Payload, PbMetric = _schema()

_U64 = 1 << 64


@dataclass(slots=True)
class Value:
    """One metric value to send: ``alias`` (and ``name`` in a birth), its type, the value
    (None: null), its time (ms since the epoch), and whether it is stored-and-forwarded
    history. In a birth, ``unit`` becomes the metric's ``engUnit`` property, ``limits``
    (low, high) its ``engLow`` and ``engHigh``, ``description`` its ``description``."""

    alias: int
    datatype: DataType
    value: Any
    timestamp: int
    name: str | None = None
    historical: bool = False
    unit: str | None = None
    limits: tuple[float, float] | None = None
    description: str = ""


def encode(timestamp: int, values: Iterable[Value], seq: int | None) -> bytes:
    """A payload: its time (ms), its metrics, its ``seq`` (None: an NDEATH has none)."""
    p = Payload(timestamp=timestamp)
    if seq is not None:
        p.seq = seq
    metrics = p.metrics
    for v in values:
        m = metrics.add(alias=v.alias, timestamp=v.timestamp)
        if v.name is not None:  # a birth names each metric and gives its type
            m.name = v.name
            m.datatype = v.datatype
            props = m.properties
            if v.unit is not None:
                props.keys.append("engUnit")
                props.values.add(type=DataType.STRING, string_value=v.unit)
            if v.limits is not None:
                props.keys.extend(("engLow", "engHigh"))
                props.values.add(type=DataType.DOUBLE, double_value=float(v.limits[0]))
                props.values.add(type=DataType.DOUBLE, double_value=float(v.limits[1]))
            if v.description:
                props.keys.append("description")
                props.values.add(type=DataType.STRING, string_value=v.description)
        if v.historical:
            m.is_historical = True
        _set_value(m, v.datatype, v.value)
    return bytes(p.SerializeToString())


def _set_value(m: Any, datatype: DataType, value: Any) -> None:
    if value is None:
        m.is_null = True
    elif datatype is DataType.BOOLEAN:
        m.boolean_value = bool(value)
    elif datatype is DataType.INT64:
        m.long_value = int(value) % _U64  # two's complement, as the specification says
    elif datatype is DataType.DOUBLE:
        m.double_value = float(value)
    else:
        m.string_value = str(value)


# -- commands ------------------------------------------------------------------------


class CommandError(SoftplcError, ValueError):
    """A command payload refused whole: not a payload, too large, too many metrics, a
    metric without a name or alias, or a value of no type a command may carry."""


@dataclass(frozen=True, slots=True)
class Command:
    """One metric of a command: its name or alias (one of them at least), its declared
    type (UNKNOWN if none) and its value as Python (bool, int, float, str)."""

    name: str | None
    alias: int | None
    datatype: DataType
    value: Any


_SIGNED = {DataType.INT8: 8, DataType.INT16: 16, DataType.INT32: 32, DataType.INT64: 64}


def decode_command(data: bytes) -> list[Command]:
    """An NCMD or DCMD payload -> its metrics; CommandError says why it is refused."""
    if len(data) > COMMAND_MAX_BYTES:
        raise CommandError(f"{len(data)} bytes (at most {COMMAND_MAX_BYTES})")
    p = Payload()
    try:
        p.ParseFromString(data)
    except (DecodeError, RecursionError, ValueError) as exc:
        raise CommandError(f"not a Sparkplug B payload ({exc or 'undecodable'})") from None
    if len(p.metrics) > COMMAND_MAX_METRICS:
        raise CommandError(f"{len(p.metrics)} metrics (at most {COMMAND_MAX_METRICS})")
    if not p.metrics:
        raise CommandError("no metric")
    out: list[Command] = []
    for m in p.metrics:
        name = m.name if m.HasField("name") else None
        alias = m.alias if m.HasField("alias") else None
        if name is None and alias is None:
            raise CommandError("a metric with neither name nor alias")
        label = name if name is not None else f"alias {alias}"
        try:
            datatype = DataType(m.datatype) if m.HasField("datatype") else DataType.UNKNOWN
        except ValueError:
            raise CommandError(f"{label}: datatype {m.datatype} is not one a command may "
                               "carry") from None
        if m.is_null:
            raise CommandError(f"{label}: a null value")
        kind = m.WhichOneof("value")
        if kind is None:
            raise CommandError(f"{label}: no value of a type a command may carry")
        value = getattr(m, kind)
        if kind == "long_value" and datatype in _SIGNED and value >= 1 << 63:
            value -= _U64
        elif kind == "int_value" and datatype in _SIGNED:
            bits = _SIGNED[datatype]
            value = value - (1 << 32) if value >= 1 << 31 and bits <= 32 else value
        elif kind in ("float_value", "double_value") and not math.isfinite(value):
            raise CommandError(f"{label}: {value} is not a finite number")
        elif kind == "string_value" and len(value) > COMMAND_MAX_TEXT:
            raise CommandError(f"{label}: a text of {len(value)} characters (at most "
                               f"{COMMAND_MAX_TEXT})")
        elif kind == "bytes_value":
            raise CommandError(f"{label}: bytes are no value of a plant")
        out.append(Command(name, alias, datatype, value))
    return out


def command_payload(timestamp: int, commands: Iterable[Command]) -> bytes:
    """A command payload (what a host application sends; tests and benchmarks)."""
    p = Payload(timestamp=timestamp)
    for c in commands:
        m = p.metrics.add(timestamp=timestamp, datatype=c.datatype)
        if c.name is not None:
            m.name = c.name
        if c.alias is not None:
            m.alias = c.alias
        _set_value(m, c.datatype, c.value)
    return bytes(p.SerializeToString())
