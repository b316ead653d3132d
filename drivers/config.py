"""Driver configuration: each key's kind, default, range and choices, declared once.

``drivers.registry`` declares every driver type's keys with ``ConfigKey``; ``ConfigKeys.
validate`` is the only place a configuration value is checked and converted (called by
``Driver.__init__``, so ``compile``, ``check`` and ``run`` refuse the same values with the
same words). No bus library is imported here: the plant loader reads the declarations even
where smbus2, gpiod or canopen are missing.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from drivers.durations import CONFIG, MAX_NS, NS_PER_S, parse_ns, strip_time_prefix


class ConfigError(ValueError):
    """A driver's configuration has a bad value: ``parity: X``, ``address: 300``, ``bias: up``.

    Raised when the plant is loaded (``runtime.language.plantfile``) and again when the
    driver is constructed, before anything touches the bus. ``key`` names the config key
    refused (None: not one key), so the loader can point at its place in the file.
    """

    def __init__(self, message: str, key: str | None = None) -> None:
        super().__init__(message)
        self.key = key


class Kind(enum.Enum):
    """What a driver config value is written as in the plant file (``ConfigKey.kind``)."""

    TEXT = "text"
    INT = "int"
    BOOL = "bool"
    #: a time (``5ms``, ``T#5ms``) or a number of seconds: drivers.config.parse_duration
    DURATION = "duration"
    #: one of ``ConfigKey.choices``
    CHOICE = "choice"
    #: a 7-bit I2C address: an int (0x20 reads as 32) or the text ``"0x20"``
    I2C_ADDRESS = "i2c address"
    #: text or an int (a python-can channel: ``can0`` or 0)
    TEXT_OR_INT = "text or int"
    #: a mapping, checked by the driver
    MAPPING = "mapping"


@dataclass(frozen=True, slots=True)
class ConfigKey:
    """One key of a driver's config: its kind, default, range, choices and the words of its
    refusal. Each type's are declared in drivers.registry; ``check`` is the only place a
    value is checked (``ConfigKeys.validate``, called by ``Driver.__init__``)."""

    name: str
    kind: Kind
    #: the value when the key is absent (None: no value, or required)
    default: Any = None
    required: bool = False
    #: inclusive bounds: of the value for INT and I2C_ADDRESS, of the length for TEXT;
    #: ``maximum`` of a DURATION is in seconds
    minimum: int | None = None
    maximum: int | None = None
    #: the inclusive ranges an INT or I2C_ADDRESS must fall in, when not one (PCF8574:
    #: 0x20-0x27 or 0x38-0x3F); ``minimum``/``maximum`` are then their outer bounds
    ranges: tuple[tuple[int, int], ...] = ()
    #: a regular expression a TEXT (or the text of a TEXT_OR_INT) must match in full
    pattern: str | None = None
    #: the values of a CHOICE
    choices: tuple[Any, ...] = ()
    #: a CHOICE read in any case (parity: ``e`` is ``E``)
    any_case: bool = False
    #: other spellings of a CHOICE, (alias, choice) pairs (parity: ``even`` is ``E``)
    aliases: tuple[tuple[str, Any], ...] = ()
    #: a DURATION that must be more than 0 (every duration is at least 0)
    positive: bool = False
    #: what the value should be, as the refusal says it ("a node-ID 1-127"); "" says it
    #: from the kind, range and choices
    expected: str = ""
    #: the refusal after ``driver NAME (TYPE): ``; fields ``key``, ``value``, ``expected``
    message: str = "{key}: expected {expected}, found {value!r}"
    #: a further check of a MAPPING's inside: the value -> None, or what is wrong with it
    #: (the refusal says it after ``driver NAME (TYPE): KEY``)
    verify: Callable[[Any], str | None] | None = None
    #: what the key is, in the words editors show (configs/schema/plant.schema.json)
    doc: str = ""
    #: what editors check of a MAPPING's inside, as JSON Schema keywords (``verify`` is the
    #: loader's check of it)
    inside: Mapping[str, Any] | None = None

    def describe(self) -> str:
        """What the value should be, in the words of a refusal."""
        if self.expected:
            return self.expected
        low, high = self.minimum, self.maximum
        if self.kind is Kind.INT:
            return "an integer" + _range_words(low, high, str)
        if self.kind is Kind.I2C_ADDRESS:
            return "an I2C address" + _range_words(low, high, lambda n: f"0x{n:02x}")
        if self.kind is Kind.TEXT:
            return "non-empty text" if low else "text"
        if self.kind is Kind.CHOICE:
            return "one of " + ", ".join(str(c) for c in self.choices)
        return {Kind.BOOL: "true or false", Kind.DURATION: "a positive time",
                Kind.TEXT_OR_INT: "text or an integer", Kind.MAPPING: "a mapping"}[self.kind]

    def refusal(self, value: Any, driver: str, type_name: str) -> ConfigError:
        """The ConfigError that refuses ``value`` for this key of ``driver``."""
        if "{value!r}" not in self.message and isinstance(value, str) and (
                not value.isprintable()):  # one line: a newline or a control shown escaped
            value = repr(value)[1:-1]
        text = self.message.format(key=self.name, value=value, expected=self.describe())
        return ConfigError(f"driver {driver} ({type_name}): {text}", self.name)

    def check(self, value: Any, driver: str, type_name: str) -> Any:
        """``value`` as the driver uses it (a time in seconds, an I2C address as an int, a
        CHOICE as declared); raises ``refusal`` (or parse_duration's ConfigError)."""
        if self.kind is Kind.DURATION:
            try:
                seconds = parse_duration(value, f"driver {driver} ({type_name}): {self.name}")
            except ConfigError as exc:
                raise ConfigError(str(exc), self.name) from None
            if ((self.positive and seconds <= 0)
                    or (self.maximum is not None and seconds > self.maximum)):
                raise self.refusal(value, driver, type_name)
            return seconds
        ok, out = self._convert(value)
        if not ok:
            raise self.refusal(value, driver, type_name)
        if self.verify is not None:
            problem = self.verify(out)
            if problem is not None:
                raise ConfigError(f"driver {driver} ({type_name}): {self.name}{problem}",
                                  self.name)
        return out

    def _convert(self, value: Any) -> tuple[bool, Any]:
        kind = self.kind
        if kind is Kind.CHOICE:
            return self._choice(value)
        if kind is Kind.BOOL:
            return isinstance(value, bool), value
        if kind is Kind.MAPPING:
            return isinstance(value, Mapping), value
        if kind is Kind.TEXT_OR_INT:
            return (_is_int(value) or (isinstance(value, str) and self._matches(value)),
                    value)
        if kind is Kind.TEXT:
            return (isinstance(value, str) and self._in_range(len(value))
                    and self._matches(value)), value
        if kind is Kind.I2C_ADDRESS and isinstance(value, str):
            try:
                value = int(value, 0)
            except ValueError:
                return False, value
        ok = _is_int(value) and self._in_range(value) and (
            not self.ranges or any(low <= value <= high for low, high in self.ranges))
        return ok, value

    def _matches(self, text: str) -> bool:
        # no text of a driver holds NUL: a path or name would be cut there by the kernel,
        # and Python refuses it with a traceback when the driver opens
        return "\0" not in text and (
            self.pattern is None or re.fullmatch(self.pattern, text) is not None)

    def _choice(self, value: Any) -> tuple[bool, Any]:
        def same(a: Any, b: Any) -> bool:
            if self.any_case and isinstance(a, str) and isinstance(b, str):
                return a.upper() == b.upper()
            return a == b and isinstance(a, bool) == isinstance(b, bool)

        for spelling, choice in (*((c, c) for c in self.choices), *self.aliases):
            if same(value, spelling):
                return True, choice
        return False, value

    def _in_range(self, n: int) -> bool:
        return ((self.minimum is None or n >= self.minimum)
                and (self.maximum is None or n <= self.maximum))


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _range_words(low: int | None, high: int | None, show: Callable[[int], str]) -> str:
    if low is not None and high is not None:
        return f" from {show(low)} to {show(high)}"
    if low is not None:
        return f" of at least {show(low)}"
    if high is not None:
        return f" of at most {show(high)}"
    return ""


#: a check across keys: the validated params -> None, or (key, what is wrong), the refusal
#: then saying ``driver NAME (TYPE): KEY: what is wrong``
CrossCheck = Callable[[Mapping[str, Any]], "tuple[str, str] | None"]


class ConfigKeys(Mapping[str, ConfigKey]):
    """The keys of one driver type, by name, in declaration order (the order messages use),
    and the checks across keys (``cross``: a socketcan channel is a network interface)."""

    def __init__(self, *keys: ConfigKey, cross: tuple[CrossCheck, ...] = ()) -> None:
        self._keys = {k.name: k for k in keys}
        self._cross = cross

    def __getitem__(self, name: str) -> ConfigKey:
        return self._keys[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def value(self, config: Mapping[str, Any], name: str) -> Any:
        """``config[name]``, or the declared default when the key is absent."""
        return config.get(name, self._keys[name].default)

    def validate(self, config: Mapping[str, Any], driver: str, type_name: str) -> dict[str, Any]:
        """Every declared key of ``driver``'s ``config`` as the driver uses it (see
        ``ConfigKey.check``), its default when absent; an optional key without a default
        may be absent or null (None). Checked in declaration order; the first bad value
        raises ConfigError. Keys not declared here are ignored (Driver refuses them)."""
        out: dict[str, Any] = {}
        for key in self._keys.values():
            if key.name in config:
                value = config[key.name]
            elif key.required:
                raise key.refusal(None, driver, type_name)
            else:
                value = key.default
            if value is None and key.default is None and not key.required:
                out[key.name] = None
            else:
                out[key.name] = key.check(value, driver, type_name)
        for rule in self._cross:
            found = rule(out)
            if found is not None:
                raise ConfigError(f"driver {driver} ({type_name}): {found[0]}: {found[1]}",
                                  found[0])
        return out

    def __repr__(self) -> str:
        return f"ConfigKeys({', '.join(self._keys)})"


def parse_duration(value: Any, what: str) -> float:
    """A duration from a driver config, in seconds.

    Accepts a number of seconds (``0.005``) or a time string (``5ms``, ``1s500ms``,
    ``250us``, ``T#20ms``; the ``durations.CONFIG`` grammar), at most ``durations.MAX_NS``
    (292 years). Raises ConfigError naming ``what`` otherwise (a NaN, an infinity, a time
    of 400 digits).
    """
    if isinstance(value, bool):
        raise ConfigError(f"{what}: expected a time such as 5ms or 0.005, found {value!r}")
    if isinstance(value, (int, float)):
        if not math.isfinite(value) or value > MAX_NS / NS_PER_S:
            raise ConfigError(f"{what}: expected a time such as 5ms or 0.005, found {value!r}")
        if value < 0:
            raise ConfigError(f"{what}: expected a positive time, found {value!r}")
        return float(value)
    if isinstance(value, str):
        ns = parse_ns(strip_time_prefix(value.strip()), CONFIG)
        if ns is not None and ns <= MAX_NS:
            return ns / NS_PER_S
    raise ConfigError(f"{what}: expected a time such as 5ms or 0.005, found {value!r}")
