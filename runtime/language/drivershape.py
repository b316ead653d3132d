"""The shape of a plant file's ``drivers:`` entries: each driver type's keys as
drivers/registry.py declares them (``DRIVER_KEYS``), for the loader (``keys_of``, the
``on_fault`` choices) and for the editors' schema (``DRIVER``, one branch per type).

The drivers' declarations are the bottom layer (drivers never import ``runtime/``): this
module only reads them, so a key a driver type declares reaches the loader and the schema
together."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from drivers.config import ConfigKey, Kind
from drivers.registry import DRIVER_KEYS, DRIVER_WORDS
from runtime.language.shape import TIME, Choice, Def, Number, Schema, Value, any_of

#: the keys every driver takes besides its type's: what the loader and Driver handle
COMMON_KEYS = ("type", "on_fault")
#: what a driver's fault does (``on_fault``), the first the default
ON_FAULT_CHOICES = ("stop", "hold", "zero")
ON_FAULT = Def("onFault", Choice(ON_FAULT_CHOICES),
               "What a fault of this driver does: stop (every output off, charts stopped), "
               "hold (run on the last good values, flagged), zero (run with this driver's "
               "inputs read as 0).", default=ON_FAULT_CHOICES[0])
DURATION = Def("duration", any_of(TIME, Number(minimum=0)),
               "A time (5ms, T#5ms) or a number of seconds (0.005).")


def keys_of(type_name: str) -> tuple[str, ...]:
    """The keys a driver of ``type_name`` takes, in the order messages list them."""
    return (*COMMON_KEYS, *DRIVER_KEYS[type_name])


def on_fault_words() -> str:
    """The choices of ``on_fault`` as a refusal says them: ``stop, hold or zero``."""
    *first, last = ON_FAULT_CHOICES
    return f"{', '.join(first)} or {last}"


def _digits(values: list[int], show: Any) -> str:
    """A character class of the one-digit ``values`` (``show``: their digit as text)."""
    chars = "".join(show(v) for v in values)
    return chars if len(chars) == 1 else f"[{chars}]"


def _hex_digit(v: int) -> str:
    d = f"{v:x}"
    return d if d.isdigit() else d + d.upper()


def address_pattern(ranges: tuple[tuple[int, int], ...]) -> str:
    """A JSON Schema pattern of the texts an I2C address in ``ranges`` is written as:
    ``0x20`` (either case of x and the hex digits) or ``32``."""
    values = [v for low, high in ranges for v in range(low, high + 1)]
    alts: list[str] = []
    for high in dict.fromkeys(v >> 4 for v in values):
        low = [v & 15 for v in values if v >> 4 == high]
        alts.append(f"0[xX]{_hex_digit(high)}{_digits(low, _hex_digit)}")
    for tens in dict.fromkeys(v // 10 for v in values):
        units = [v % 10 for v in values if v // 10 == tens]
        alts.append(f"{tens or ''}{_digits(units, str)}")
    return f"^({'|'.join(alts)})$"


def _address_def(type_name: str, key: ConfigKey) -> Def:
    ranges = key.ranges or ((key.minimum or 0, key.maximum or 0x7F),)
    spans = " or ".join(f"0x{low:02X}-0x{high:02X}" for low, high in ranges)
    return Def(f"{type_name}Address", _Address(ranges),
               f"An I2C address {spans}: 0x{ranges[0][0]:02x} (YAML reads it as the integer "
               f"{ranges[0][0]}) or the string \"0x{ranges[0][0]:02x}\".")


@dataclass(frozen=True)
class _Address(Value):
    ranges: tuple[tuple[int, int], ...]

    def schema(self) -> Schema:
        return {"anyOf": [*({"type": "integer", "minimum": low, "maximum": high}
                            for low, high in self.ranges),
                          {"type": "string", "pattern": address_pattern(self.ranges)}]}


def key_schema(type_name: str, key: ConfigKey) -> Schema:
    """One declared key of a driver type as editors check it."""
    kind = key.kind
    s: Schema
    if kind is Kind.TEXT:
        s = {"type": "string"}
        if key.minimum is not None:
            s["minLength"] = key.minimum
        if key.maximum is not None:
            s["maxLength"] = key.maximum
        if key.pattern is not None:
            s["pattern"] = f"^(?:{key.pattern})$"
    elif kind is Kind.INT:
        s = {"type": "integer"}
        if key.minimum is not None:
            s["minimum"] = key.minimum
        if key.maximum is not None:
            s["maximum"] = key.maximum
    elif kind is Kind.BOOL:
        s = {"type": "boolean"}
    elif kind is Kind.DURATION:
        s = DURATION.schema()
    elif kind is Kind.CHOICE:
        choices = list(key.choices)
        if key.any_case:
            choices += [c.lower() for c in key.choices if isinstance(c, str) and c != c.lower()]
        s = {"enum": choices}
    elif kind is Kind.I2C_ADDRESS:
        s = _address_def(type_name, key).schema()
    elif kind is Kind.TEXT_OR_INT:
        s = {"type": ["string", "integer"]}
    elif kind is Kind.MAPPING:
        s = {"type": "object", **(key.inside or {})}
    else:  # pragma: no cover - a new Kind needs a rule here
        raise AssertionError(kind)
    if key.default is not None and kind is not Kind.DURATION:  # a duration's is in seconds
        s["default"] = key.default
    if key.doc:
        s["description"] = key.doc
    return s


@dataclass(frozen=True)
class _Driver(Value):
    """A driver: its type, then the keys of that type (one ``if``/``then`` per type)."""

    def schema(self) -> Schema:
        branches = []
        for type_name, keys in DRIVER_KEYS.items():
            then: Schema = {"properties": {
                "type": {"const": type_name, "description": f"Driver type {type_name}."},
                "on_fault": ON_FAULT.schema(),
                **{name: key_schema(type_name, key) for name, key in keys.items()}},
                "additionalProperties": False}
            required = [name for name, key in keys.items() if key.required]
            if required:
                then["required"] = required
            branches.append({"if": {"properties": {"type": {"const": type_name}},
                                    "required": ["type"]},
                             "then": then})
        return {
            "type": "object",
            "required": ["type"],
            "properties": {
                "type": {"enum": list(DRIVER_KEYS), "description": ", ".join(
                    f"{t} ({DRIVER_WORDS[t]})" for t in DRIVER_KEYS) + "."},
                "on_fault": ON_FAULT.schema()},
            "allOf": branches}

    def defs(self) -> Iterator[Def]:
        yield from ON_FAULT.defs()
        yield from DURATION.defs()
        for type_name, keys in DRIVER_KEYS.items():
            for key in keys.values():
                if key.kind is Kind.I2C_ADDRESS:
                    yield _address_def(type_name, key)


DRIVER = Def("driver", _Driver(),
             "An I/O driver. Its points are named driver.point in the bindings; every driver "
             "also offers driver.ok (read-only: healthy).")
