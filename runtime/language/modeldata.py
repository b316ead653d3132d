"""A loaded plant (or any piece of the model) as plain data and back: how a load made in
another process crosses to this one, as JSON, never as pickle.

The reload's child process (runtime/controller/reloadchild.py) loads the plant file and its
charts; the controller takes the ``PlantDef`` it made. Pickle would run whatever the bytes
name when they are read; this encoding names only the model's own classes (the dataclasses
and enums of ``language.model``, ``language.ast`` and ``errors.Loc``, and every one their
fields' types name, such as the I/O list's ``units.Unit``: a table built from those modules
and their type hints) and plain values (None, bool, int, float, str, list, tuple, dict),
and builds each object from its fields' values, calling nothing the data chooses.

The objects are written as *records* in post-order, each one a JSON list whose first item
says what it is (``o`` a model object with its class and fields in declaration order, ``e``
an enum member, ``l`` ``t`` ``d`` a list, tuple or dict); a value inside a record is a plain
JSON scalar or ``[n]``, the object of record n. An object met twice is written once, so the
load keeps what the loader shares (one ``Grafcet`` for every instance of a chart file, which
the engine compiles once, by identity). The records go in chunks of at most
``CHUNK_RECORDS`` each, so that reading them holds the GIL for a short time per chunk (one
``json.loads`` of a whole 2000-step chart is a single call of tens of ms, the scan thread
waiting meanwhile).

What only the load itself needs is not carried: the ``locate`` functions of conditions and
actions (positions inside a text, for the load's own error messages) become None, and the
YAML strings that know their positions become plain ``str``.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import typing
from collections.abc import Iterable, Iterator
from typing import Any

from runtime.errors import Loc, SoftplcError
from runtime.language import ast as A
from runtime.language import model as M

#: records per chunk (about 50 kB of JSON, read in about 1 ms)
CHUNK_RECORDS = 1000
#: the fields left out (None): functions that only the load's error messages use
LEFT_OUT = frozenset({"locate"})


class ModelDataError(SoftplcError, ValueError):
    """Data that is not a model written by :func:`dump` (a class not of the model, a
    field count that does not match, a reference to a record not read yet)."""


def _classes() -> dict[str, type]:
    """The classes data may name, by name: the dataclasses and enums of the model's modules,
    and every dataclass or enum their fields' types name, wherever it is defined (the I/O
    list's ``units.Unit``), found by following the type hints: a class the model takes in
    crosses with it, never "not part of the model"."""
    out: dict[str, type] = {}
    todo: list[type] = [Loc]
    for module in (A, M):
        todo += [cls for cls in vars(module).values()
                 if isinstance(cls, type) and cls.__module__ == module.__name__ and (
                     dataclasses.is_dataclass(cls) or issubclass(cls, enum.Enum))]
    while todo:
        cls = todo.pop()
        if out.setdefault(cls.__name__, cls) is not cls:
            raise AssertionError(f"two model classes named {cls.__name__}")
        if dataclasses.is_dataclass(cls):
            for hint in typing.get_type_hints(cls).values():
                todo += [c for c in _named(hint) if c.__name__ not in out]
    return out


def _named(hint: Any) -> Iterator[type]:
    """The dataclasses and enums a type hint names (inside unions, lists, dicts...)."""
    if isinstance(hint, type) and (dataclasses.is_dataclass(hint)
                                   or issubclass(hint, enum.Enum)):
        yield hint
    for arg in typing.get_args(hint):
        yield from _named(arg)


CLASSES = _classes()
_SCALARS = (type(None), bool, int, float)


class _Writer:
    """Writes the records of one object graph (post-order, each object once)."""

    def __init__(self) -> None:
        self.records: list[list[Any]] = []
        self._ids: dict[int, int] = {}
        self._keep: list[Any] = []  # the objects whose id() is a key: alive until the end

    def value(self, v: Any) -> Any:
        """``v`` as it is written inside a record."""
        if type(v) in _SCALARS:
            return v
        if isinstance(v, enum.Enum):
            return [self.record(v)]
        if isinstance(v, str):  # a YAML string that knows its positions: the text
            return str(v)
        if isinstance(v, int | float):  # a subclass of a number: its plain value
            return float(v) if isinstance(v, float) else int(v)
        return [self.record(v)]

    def record(self, v: Any) -> int:
        """The number of the record of object ``v`` (written now if it is new)."""
        n = self._ids.get(id(v))
        if n is not None:
            return n
        cls = type(v)
        rec: list[Any]
        if isinstance(v, enum.Enum) and CLASSES.get(cls.__name__) is cls:
            rec = ["e", cls.__name__, v.value]
        elif dataclasses.is_dataclass(v) and CLASSES.get(cls.__name__) is cls:
            rec = ["o", cls.__name__]
            rec += [None if f.name in LEFT_OUT else self.value(getattr(v, f.name))
                    for f in dataclasses.fields(v)]
        elif isinstance(v, tuple):
            rec = ["t", *(self.value(x) for x in v)]
        elif isinstance(v, list):
            rec = ["l", *(self.value(x) for x in v)]
        elif isinstance(v, dict):
            rec = ["d"]
            for k, x in v.items():
                rec += [self.value(k), self.value(x)]
        else:
            raise ModelDataError(f"{cls.__name__} is not part of the model: it cannot cross "
                                 "as data")
        n = self._ids[id(v)] = len(self.records)
        self.records.append(rec)
        self._keep.append(v)
        return n


def dump(obj: Any) -> Iterator[str]:
    """``obj`` (a PlantDef, a Grafcet, any model object) as chunks of JSON text, in order;
    :func:`load` of the chunks gives it back. ModelDataError for anything not of the model."""
    w = _Writer()
    w.record(obj)
    records = w.records
    for i in range(0, len(records), CHUNK_RECORDS):
        yield json.dumps(records[i:i + CHUNK_RECORDS], ensure_ascii=False,
                         separators=(",", ":"))


def load(chunks: Iterable[str | bytes]) -> Any:
    """The object whose chunks :func:`dump` wrote (its last record). ModelDataError if the
    data is not such chunks."""
    objs: list[Any] = []
    for chunk in chunks:
        try:
            records = json.loads(chunk)
        except ValueError as exc:
            raise ModelDataError(f"not JSON: {exc}") from None
        if not isinstance(records, list):
            raise ModelDataError("a chunk is not a list of records")
        for rec in records:
            objs.append(_build(rec, objs))
    if not objs:
        raise ModelDataError("no record")
    return objs[-1]


def _build(rec: Any, objs: list[Any]) -> Any:
    """The object of one record; ``objs``: the objects of the records before it."""
    if not isinstance(rec, list) or not rec or not isinstance(rec[0], str):
        raise ModelDataError(f"not a record: {str(rec)[:60]}")
    tag = rec[0]

    def value(x: Any) -> Any:
        if isinstance(x, list):
            if len(x) != 1 or type(x[0]) is not int or not 0 <= x[0] < len(objs):
                raise ModelDataError(f"bad reference {str(x)[:60]}")
            return objs[x[0]]
        if type(x) not in _SCALARS and not isinstance(x, str):
            raise ModelDataError(f"bad value {str(x)[:60]}")
        return x

    if tag == "l":
        return [value(x) for x in rec[1:]]
    if tag == "t":
        return tuple(value(x) for x in rec[1:])
    if tag == "d":
        items = rec[1:]
        if len(items) % 2:
            raise ModelDataError("a dict record with an odd number of items")
        try:
            return {value(items[i]): value(items[i + 1]) for i in range(0, len(items), 2)}
        except TypeError:
            raise ModelDataError("a dict record with a key that is not hashable") from None
    cls = CLASSES.get(rec[1]) if len(rec) > 1 and isinstance(rec[1], str) else None
    if tag == "e" and cls is not None and issubclass(cls, enum.Enum) and len(rec) == 3:
        try:
            return cls(rec[2])
        except (ValueError, TypeError):
            raise ModelDataError(f"{rec[1]} has no member {rec[2]!r}") from None
    if tag == "o" and cls is not None and dataclasses.is_dataclass(cls):
        fields = dataclasses.fields(cls)
        if len(rec) - 2 != len(fields):
            raise ModelDataError(f"{rec[1]}: {len(rec) - 2} fields, expected {len(fields)}")
        obj = object.__new__(cls)
        for f, x in zip(fields, rec[2:], strict=True):
            object.__setattr__(obj, f.name, value(x))
        return obj
    raise ModelDataError(f"unknown record {str(rec[:2])[:60]}")
