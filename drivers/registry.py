"""Driver lookup by the plant file's ``type:`` key, importing back-ends lazily."""

from __future__ import annotations

import importlib

from drivers.base import Driver

#: type -> (module, class name, pip package that provides its bus library)
DRIVERS: dict[str, tuple[str, str, str | None]] = {
    "sim": ("drivers.sim", "SimDriver", None),
    "gpio": ("drivers.gpio", "GpioDriver", "gpiod"),
    "mcp23017": ("drivers.mcp23017", "Mcp23017Driver", "smbus2"),
    "pcf8574": ("drivers.pcf8574", "Pcf8574Driver", "smbus2"),
    "canopen": ("drivers.canopen_io", "CanopenDriver", "canopen"),
    "modbus_rtu": ("drivers.modbus_rtu", "ModbusRtuDriver", "pyserial"),
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
        raise DriverImportError(
            f"driver type '{type_name}' needs the Python package '{package}'{missing}: "
            f"pip install {package}"
        ) from exc
    cls: type[Driver] = getattr(module, class_name)
    return cls
