"""The config keys of every driver type, declared once: name, kind, default, range.

A plant file's ``drivers:`` entry is checked against these before any driver is built,
so this module must load on a machine without the bus libraries (smbus2, gpiod, canopen,
pyserial): the driver modules import theirs at the top, so the declarations live here,
in a module that imports nothing but the standard library, and each driver class points
to its own (``config_keys = GPIO_KEYS``). Who reads them:

- ``Driver.__init__`` refuses a key its class does not declare;
- ``runtime.language.plantfile`` refuses a key its type does not declare (with the place in
  the file and a suggestion);
- each driver takes its defaults from here (``KEYS["baudrate"].default``) and checks its own
  values, with its own messages;
- ``tests/drivers/test_config_keys.py`` checks that configs/schema/plant.schema.json
  describes exactly these keys, with compatible kinds, defaults and ranges.

``type`` and ``on_fault`` are every driver's keys and are not listed.
"""

from __future__ import annotations

import enum
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any


class Kind(enum.Enum):
    """What a config value is written as in the plant file."""

    TEXT = "text"
    INT = "int"
    BOOL = "bool"
    #: a time (``5ms``, ``T#5ms``) or a number of seconds: drivers.base.parse_duration
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
    """One key of a driver's config."""

    name: str
    kind: Kind
    #: the value when the key is absent (None: no value, or required)
    default: Any = None
    required: bool = False
    #: inclusive bounds the driver checks, for INT and I2C_ADDRESS
    minimum: int | None = None
    maximum: int | None = None
    #: the values of a CHOICE
    choices: tuple[Any, ...] = ()
    #: a CHOICE read in any case (parity: ``e`` is ``E``)
    any_case: bool = False


class ConfigKeys(Mapping[str, ConfigKey]):
    """The keys of one driver type, by name, in declaration order (the order messages use)."""

    def __init__(self, *keys: ConfigKey) -> None:
        self._keys = {k.name: k for k in keys}

    def __getitem__(self, name: str) -> ConfigKey:
        return self._keys[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys)

    def __len__(self) -> int:
        return len(self._keys)

    def value(self, config: Mapping[str, Any], name: str) -> Any:
        """``config[name]``, or the declared default when the key is absent."""
        return config.get(name, self._keys[name].default)

    def __repr__(self) -> str:
        return f"ConfigKeys({', '.join(self._keys)})"


SIM_KEYS = ConfigKeys()

GPIO_KEYS = ConfigKeys(
    ConfigKey("chip", Kind.TEXT, default="/dev/gpiochip0"),
    ConfigKey("bias", Kind.CHOICE, default="none", choices=("pull_up", "pull_down", "none")),
    ConfigKey("debounce", Kind.DURATION, default=0),
)

MCP23017_KEYS = ConfigKeys(
    ConfigKey("bus", Kind.INT, required=True, minimum=0),
    ConfigKey("address", Kind.I2C_ADDRESS, required=True, minimum=0x03, maximum=0x77),
    ConfigKey("pull_up", Kind.BOOL, default=True),
)

PCF8574_KEYS = ConfigKeys(
    ConfigKey("bus", Kind.INT, required=True, minimum=0),
    ConfigKey("address", Kind.I2C_ADDRESS, required=True, minimum=0x03, maximum=0x77),
)

CANOPEN_KEYS = ConfigKeys(
    ConfigKey("interface", Kind.TEXT, default="socketcan"),
    ConfigKey("channel", Kind.TEXT_OR_INT, default="can0"),
    ConfigKey("bitrate", Kind.INT, minimum=1),
    ConfigKey("node", Kind.INT, required=True, minimum=1, maximum=127),
    ConfigKey("heartbeat", Kind.DURATION, default=1.0),
    ConfigKey("eds", Kind.TEXT),
    ConfigKey("sync", Kind.DURATION),
    ConfigKey("pdo", Kind.MAPPING),
)

MODBUS_RTU_KEYS = ConfigKeys(
    ConfigKey("port", Kind.TEXT, required=True),
    ConfigKey("baudrate", Kind.INT, default=19200, minimum=1),
    ConfigKey("parity", Kind.CHOICE, default="N", choices=("N", "E", "O"), any_case=True),
    ConfigKey("unit", Kind.INT, default=1, minimum=1, maximum=247),
    ConfigKey("timeout", Kind.DURATION, default=0.1),
    ConfigKey("retries", Kind.INT, default=2, minimum=0, maximum=10),
    ConfigKey("stopbits", Kind.CHOICE, default=1, choices=(1, 2)),
)

#: driver type (the plant file's ``type:``) -> its keys; the same types as drivers.registry
DRIVER_KEYS: dict[str, ConfigKeys] = {
    "sim": SIM_KEYS,
    "gpio": GPIO_KEYS,
    "mcp23017": MCP23017_KEYS,
    "pcf8574": PCF8574_KEYS,
    "canopen": CANOPEN_KEYS,
    "modbus_rtu": MODBUS_RTU_KEYS,
}
