"""Driver types: lookup by the plant file's ``type:`` key (importing back-ends lazily), and
the config keys of each type, declared once: kind, default, range, choices, and the
words of a refusal.

The declarations live here, not in the driver modules, because those import their bus
library (smbus2, gpiod, canopen, pyserial) at the top, and the keys must be readable
without it: ``runtime.language.plantfile`` checks a plant file's ``drivers:`` against them
on a machine where the libraries are missing (``softplc check`` on a desktop). Who reads
them: ``Driver.__init__`` refuses a key its class does not declare (each class points to
its declaration: ``config_keys = GPIO_KEYS``); the plant loader refuses a key its type does
not declare (with the place in the file and a suggestion); ``Driver.__init__`` checks
every value against its declaration (``ConfigKeys.validate``) and hands the driver
``params``, defaults filled in, so no driver checks a value or writes a default itself
(only what a kind leaves to it: the inside of canopen's ``pdo`` mapping).
``tests/drivers/test_config_keys.py`` holds configs/schema/plant.schema.json to them and
``tests/drivers/test_config_validation.py`` the drivers' behaviour at every bound and
choice. ``type`` and ``on_fault`` are every driver's keys and are not listed.
"""

from __future__ import annotations

import importlib

from drivers.base import Driver
from drivers.config import ConfigKey, ConfigKeys, Kind

#: type -> (module, class name, pip package that provides its bus library)
DRIVERS: dict[str, tuple[str, str, str | None]] = {
    "sim": ("drivers.sim", "SimDriver", None),
    "gpio": ("drivers.gpio", "GpioDriver", "gpiod"),
    "mcp23017": ("drivers.mcp23017", "Mcp23017Driver", "smbus2"),
    "pcf8574": ("drivers.pcf8574", "Pcf8574Driver", "smbus2"),
    "canopen": ("drivers.canopen_io", "CanopenDriver", "canopen"),
    "modbus_rtu": ("drivers.modbus_rtu", "ModbusRtuDriver", "pyserial"),
}


SIM_KEYS = ConfigKeys()

GPIO_KEYS = ConfigKeys(
    ConfigKey("chip", Kind.TEXT, default="/dev/gpiochip0"),
    ConfigKey("bias", Kind.CHOICE, default="none", choices=("pull_up", "pull_down", "none"),
              message="{key} '{value}': expected {expected}"),
    ConfigKey("debounce", Kind.DURATION, default=0),
)

#: the keys of an I2C chip: bus and address
_I2C_BUS = ConfigKey("bus", Kind.INT, required=True, minimum=0,
                     expected="the I2C bus number (1 for /dev/i2c-1)")
_I2C_ADDRESS = ConfigKey("address", Kind.I2C_ADDRESS, required=True, minimum=0x03,
                         maximum=0x77, expected="a 7-bit I2C address such as 0x20")

MCP23017_KEYS = ConfigKeys(
    _I2C_BUS,
    _I2C_ADDRESS,
    ConfigKey("pull_up", Kind.BOOL, default=True),
)

PCF8574_KEYS = ConfigKeys(_I2C_BUS, _I2C_ADDRESS)

CANOPEN_KEYS = ConfigKeys(
    ConfigKey("interface", Kind.TEXT, default="socketcan"),
    ConfigKey("channel", Kind.TEXT_OR_INT, default="can0"),
    ConfigKey("bitrate", Kind.INT, minimum=1, expected="a bit rate such as 250000"),
    ConfigKey("node", Kind.INT, required=True, minimum=1, maximum=127,
              expected="a node-ID 1-127"),
    ConfigKey("heartbeat", Kind.DURATION, default=1.0, positive=True,
              expected="a positive consumer timeout such as 500ms"),
    ConfigKey("eds", Kind.TEXT),
    ConfigKey("sync", Kind.DURATION, positive=True, expected="a positive SYNC period such as 10ms"),
    ConfigKey("pdo", Kind.MAPPING, message="{key}: expected {expected}",
              expected="a mapping such as {tpdo1: ['6000:1'], rpdo1: ['6200:1']}"),
)

MODBUS_RTU_KEYS = ConfigKeys(
    ConfigKey("port", Kind.TEXT, required=True, minimum=1,
              expected="a serial device such as /dev/ttyUSB0"),
    ConfigKey("baudrate", Kind.INT, default=19200, minimum=1,
              expected="a baud rate such as 19200"),
    ConfigKey("parity", Kind.CHOICE, default="N", choices=("N", "E", "O"), any_case=True,
              aliases=(("NONE", "N"), ("EVEN", "E"), ("ODD", "O")), expected="N, E or O"),
    ConfigKey("unit", Kind.INT, default=1, minimum=1, maximum=247,
              expected="a slave address 1-247"),
    ConfigKey("timeout", Kind.DURATION, default=0.1, positive=True,
              expected="a positive time such as 100ms"),
    ConfigKey("retries", Kind.INT, default=2, minimum=0, maximum=10, expected="0-10"),
    ConfigKey("stopbits", Kind.CHOICE, default=1, choices=(1, 2), expected="1 or 2"),
)

#: driver type -> its config keys; the same types, in the same order, as DRIVERS
DRIVER_KEYS: dict[str, ConfigKeys] = {
    "sim": SIM_KEYS,
    "gpio": GPIO_KEYS,
    "mcp23017": MCP23017_KEYS,
    "pcf8574": PCF8574_KEYS,
    "canopen": CANOPEN_KEYS,
    "modbus_rtu": MODBUS_RTU_KEYS,
}


#: bus libraries that are an extra of softplc, not a core dependency: package -> (extra,
#: what installing it needs). gpiod has no wheel for 32-bit ARM on PyPI: pip compiles it.
EXTRAS: dict[str, tuple[str, str]] = {
    "gpiod": ("gpio", "on 32-bit ARM pip compiles it: apt-get install gcc python3-dev first"),
}


class DriverImportError(ImportError):
    """The library a driver needs is not installed; the message names the package."""


def driver_class(type_name: str) -> type[Driver]:
    """Return the Driver class for ``type_name``; KeyError if unknown, DriverImportError if
    its library is missing."""
    module_name, class_name, package = DRIVERS[type_name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and exc.name.startswith(("drivers.", "runtime.")):
            raise
        missing = "" if exc.name in (None, package) else f" (module '{exc.name}' not found)"
        extra = EXTRAS.get(package or "")
        hint = (f"pip install 'softplc[{extra[0]}]' ({extra[1]})" if extra
                else f"pip install {package}")
        raise DriverImportError(
            f"driver type '{type_name}' needs the Python package '{package}'{missing}: {hint}"
        ) from exc
    cls: type[Driver] = getattr(module, class_name)
    return cls
