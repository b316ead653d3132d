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

The points of each type are described here too (``POINTS``: names, numbers, direction, bit
or register), for the same reason: the plant loader refuses ``exp1.C3`` on an MCP23017
where smbus2 is missing, and each driver's ``_check_point`` asks the same description.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from drivers.base import Direction, Driver, PointError, PointKind
from drivers.config import ConfigError, ConfigKey, ConfigKeys, Kind

#: type -> what it is, in the words editors show (configs/schema/plant.schema.json)
DRIVER_WORDS: dict[str, str] = {
    "sim": "in memory",
    "gpio": "Linux GPIO character device",
    "mcp23017": "I2C expander",
    "pcf8574": "I2C expander",
    "canopen": "CiA 401 node",
    "modbus_rtu": "Modbus RTU master",
    "modbus_tcp": "Modbus TCP master: a device or a gateway",
}

#: type -> (module, class name, pip package that provides its bus library)
DRIVERS: dict[str, tuple[str, str, str | None]] = {
    "sim": ("drivers.sim", "SimDriver", None),
    "gpio": ("drivers.gpio", "GpioDriver", "gpiod"),
    "mcp23017": ("drivers.mcp23017", "Mcp23017Driver", "smbus2"),
    "pcf8574": ("drivers.pcf8574", "Pcf8574Driver", "smbus2"),
    "canopen": ("drivers.canopen_io", "CanopenDriver", "canopen"),
    "modbus_rtu": ("drivers.modbus_rtu", "ModbusRtuDriver", "pyserial"),
    "modbus_tcp": ("drivers.modbus_tcp", "ModbusTcpDriver", None),
}


SIM_KEYS = ConfigKeys()

#: the longest GPIO debounce period, s: the kernel takes it in µs in 32 bits (4294.97 s)
GPIO_MAX_DEBOUNCE_S = 4294

#: the debounce period of a digital bank's inputs (drivers/bank.py): the kernel's for a GPIO
#: chip, the driver's own for an I2C expander (the same range for both)
_DEBOUNCE = ConfigKey("debounce", Kind.DURATION, default=0, maximum=GPIO_MAX_DEBOUNCE_S,
                      expected=f"a debounce period from 0 to {GPIO_MAX_DEBOUNCE_S}s such as "
                               "5ms",
                      doc="Debounce period of the input lines, by the driver (the chip has "
                          "none): a change is taken once every read for this long saw it "
                          "(10ms).")

#: a GPIO chip's label as the kernel gives it through the character device (at most 31
#: characters: GPIO_MAX_NAME_SIZE is 32 with the NUL), printable, without white space at
#: either end; not a device's name (``gpiochip0`` is a mistake for ``/dev/gpiochip0``)
GPIO_LABEL = r"(?!gpiochip[0-9]+$)[^/\x00-\x20\x7f](?:[^\x00-\x1f\x7f]{0,29}[^\x00-\x20\x7f])?"

GPIO_KEYS = ConfigKeys(
    ConfigKey("chip", Kind.TEXT, default="/dev/gpiochip0", pattern=r"/\S+|" + GPIO_LABEL,
              expected="a GPIO chip: its character device such as /dev/gpiochip0 (the "
                       "full path) or its label such as pinctrl-rp1 (gpiodetect lists "
                       "both)",
              doc="The GPIO chip: its character device (/dev/gpiochip0) or its label "
                  "(pinctrl-rp1), looked up at every open."),
    ConfigKey("bias", Kind.CHOICE, default="none", choices=("pull_up", "pull_down", "none"),
              message="{key} '{value}': expected {expected}", doc="Bias of the input lines."),
    replace(_DEBOUNCE, doc="Debounce period of the input lines (5ms)."),
)

#: the keys of an I2C chip: bus and address
_I2C_BUS = ConfigKey("bus", Kind.INT, required=True, minimum=0,
                     expected="the I2C bus number (1 for /dev/i2c-1)",
                     doc="I2C bus number: 1 for /dev/i2c-1.")

MCP23017_KEYS = ConfigKeys(
    _I2C_BUS,
    ConfigKey("address", Kind.I2C_ADDRESS, required=True, minimum=0x20, maximum=0x27,
              expected="an MCP23017 address from 0x20 to 0x27 (pins A2 A1 A0)",
              doc="0x20-0x27 (A2 A1 A0)."),
    ConfigKey("pull_up", Kind.BOOL, default=True,
              doc="The chip's 100 kΩ pull-ups on the bound inputs."),
    _DEBOUNCE,
)

PCF8574_KEYS = ConfigKeys(
    _I2C_BUS,
    ConfigKey("address", Kind.I2C_ADDRESS, required=True, minimum=0x20, maximum=0x3F,
              ranges=((0x20, 0x27), (0x38, 0x3F)),
              expected="a PCF8574 address from 0x20 to 0x27 or a PCF8574A address from "
                       "0x38 to 0x3f (pins A2 A1 A0)",
              doc="0x20-0x27 (PCF8574) or 0x38-0x3F (PCF8574A)."),
    _DEBOUNCE,
)

#: python-can's own interfaces (python-can 4): the ``interface`` of a canopen driver
CAN_INTERFACES = (
    "socketcan", "virtual", "udp_multicast", "socketcand", "slcan", "serial", "pcan",
    "kvaser", "ixxat", "vector", "gs_usb", "cantact", "canalystii", "usb2can", "seeedstudio",
    "robotell", "nican", "nixnet", "neovi", "neousys", "iscan", "systec", "etas")
#: CAN bit rates, bit/s: those of CiA 301 and 100 kbit/s
CAN_BITRATES = (10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000,
                1_000_000)
#: the longest heartbeat consumer timeout, s: the node's producer time is set to a quarter
#: of it in ms, in 16 bits (0x1017: 65535 ms)
CANOPEN_MAX_HEARTBEAT_S = 262
#: the longest SYNC period, s (0x1006 holds it in µs, in 32 bits)
CANOPEN_MAX_SYNC_S = 4294
#: a Linux network interface name: 1-15 characters, no '/', ':' or white space, not . or ..
NETDEV_NAME = re.compile(r"(?!\.{1,2}$)[^/:\s]{1,15}")

#: a mapped object of a PDO: INDEX:SUB in hex (or 6000sub1, 6000.1), /BITS if not 8
_PDO_ENTRY = re.compile(r"^(?:0x)?([0-9A-Fa-f]{1,4})(?:sub|:|\.)([0-9A-Fa-f]{1,2})"
                        r"(?:/(\d{1,2}))?$")


@dataclass(frozen=True)
class PdoEntry:
    """One object mapped into a PDO: index, sub-index and length in bits."""

    index: int
    subindex: int
    bits: int


def pdo_config(pdo: Mapping[Any, Any]) -> tuple[list[list[PdoEntry]], list[list[PdoEntry]]]:
    """``{tpdo1: ["6000:1", ...], rpdo1: [...]}`` -> (TPDO maps, RPDO maps) by number;
    ValueError saying what is wrong (after the key's name: ``: 'tpdo9': expected ...``)."""
    maps: dict[str, list[list[PdoEntry]]] = {"tpdo": [[] for _ in range(4)],
                                             "rpdo": [[] for _ in range(4)]}
    for key, entries in pdo.items():
        m = re.match(r"^(tpdo|rpdo)([1-4])$", str(key))
        if m is None or not isinstance(entries, list):
            raise ValueError(f": '{key}': expected tpdo1-tpdo4 or rpdo1-rpdo4 with a list of "
                             "mapped objects such as '6000:1'")
        parsed = []
        for text in entries:
            e = _PDO_ENTRY.match(str(text))
            bits = int(e.group(3) or 8) if e is not None else 0
            if e is None or not 1 <= bits <= 64:
                raise ValueError(f" {key}: '{text}': expected INDEX:SUB in hex, with /BITS "
                                 "if not 8 (e.g. 6000:1, 2000:0/16)")
            parsed.append(PdoEntry(int(e.group(1), 16), int(e.group(2), 16), bits))
        maps[m.group(1)][int(m.group(2)) - 1] = parsed
    return maps["tpdo"], maps["rpdo"]


def _pdo_problem(pdo: Any) -> str | None:
    try:
        pdo_config(pdo)
    except ValueError as exc:
        return str(exc)
    return None


def _socketcan_channel(params: Mapping[str, Any]) -> tuple[str, str] | None:
    """A socketcan channel is a network interface name (can0, vcan0)."""
    channel = params["channel"]
    if params["interface"] != "socketcan" or (
            isinstance(channel, str) and NETDEV_NAME.fullmatch(channel)):
        return None
    return ("channel", "expected a network interface name such as can0 (1-15 characters, "
                       f"no '/', ':' or space), found {channel!r}")


CANOPEN_KEYS = ConfigKeys(
    ConfigKey("interface", Kind.CHOICE, default="socketcan", choices=CAN_INTERFACES,
              expected="a python-can interface: " + ", ".join(CAN_INTERFACES),
              doc="python-can interface: socketcan, virtual, udp_multicast, pcan, ..."),
    ConfigKey("channel", Kind.TEXT_OR_INT, default="can0", doc="python-can channel (can0)."),
    ConfigKey("bitrate", Kind.CHOICE, choices=CAN_BITRATES,
              expected="a CAN bit rate: " + ", ".join(str(b) for b in CAN_BITRATES),
              doc="Bit rate (250000), passed to python-can."),
    ConfigKey("node", Kind.INT, required=True, minimum=1, maximum=127,
              expected="a node-ID 1-127", doc="Node-ID of the CiA 401 I/O node."),
    ConfigKey("heartbeat", Kind.DURATION, default=1.0, positive=True,
              maximum=CANOPEN_MAX_HEARTBEAT_S,
              expected=f"a positive consumer timeout such as 500ms, at most "
                       f"{CANOPEN_MAX_HEARTBEAT_S}s (the node's heartbeat is a quarter of it, "
                       "in 16-bit ms)",
              doc="Heartbeat consumer timeout (500ms; default 1 s)."),
    ConfigKey("eds", Kind.TEXT, doc="EDS/DCF file of the node (PDO mapping taken from it)."),
    ConfigKey("sync", Kind.DURATION, positive=True, maximum=CANOPEN_MAX_SYNC_S,
              expected=f"a positive SYNC period such as 10ms, at most {CANOPEN_MAX_SYNC_S}s",
              doc="SYNC period (optional): RPDOs on change, SYNC produced at this period."),
    ConfigKey("pdo", Kind.MAPPING, message="{key}: expected {expected}",
              expected="a mapping such as {tpdo1: ['6000:1'], rpdo1: ['6200:1']}",
              verify=_pdo_problem,
              doc='The PDO mapping itself: {tpdo1: ["6000:1"], rpdo1: ["6200:1"]}.',
              inside={"propertyNames": {"pattern": "^[tr]pdo[1-4]$"},
                      "additionalProperties": {"type": "array", "items": {
                          "type": "string",
                          "pattern": "^[0-9a-fA-F]{1,4}:[0-9a-fA-F]{1,2}(/[0-9]+)?$"}}}),
    cross=(_socketcan_channel,),
)

#: the serial line rates Linux sets (termios), bit/s
BAUDRATES = (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200,
             38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000,
             1500000, 2000000, 2500000, 3000000, 3500000, 4000000)

MODBUS_RTU_KEYS = ConfigKeys(
    ConfigKey("port", Kind.TEXT, required=True, pattern=r"/\S+",
              expected="a serial device such as /dev/ttyUSB0 (its full path)",
              doc="Serial device (/dev/ttyUSB0); several drivers may share one port."),
    ConfigKey("baudrate", Kind.CHOICE, default=19200, choices=BAUDRATES,
              expected="a standard baud rate such as 9600, 19200 or 115200 (50 to 4000000)",
              doc="Baud rate."),
    ConfigKey("parity", Kind.CHOICE, default="N", choices=("N", "E", "O"), any_case=True,
              aliases=(("NONE", "N"), ("EVEN", "E"), ("ODD", "O")), expected="N, E or O",
              doc="Parity: N, E or O."),
    ConfigKey("unit", Kind.INT, default=1, minimum=1, maximum=247,
              expected="a slave address 1-247", doc="Slave address."),
    ConfigKey("timeout", Kind.DURATION, default=0.1, positive=True,
              expected="a positive time such as 100ms",
              doc="Response timeout per request (100ms)."),
    ConfigKey("retries", Kind.INT, default=2, minimum=0, maximum=10, expected="0-10",
              doc="Further attempts after a timeout or a damaged reply."),
    ConfigKey("stopbits", Kind.CHOICE, default=1, choices=(1, 2), expected="1 or 2",
              doc="Stop bits."),
)

#: a host name or an IP address (IPv6 without brackets)
_HOST = re.compile(r"[A-Za-z0-9_.-]{1,253}|[0-9A-Fa-f:.]{2,45}")

MODBUS_TCP_KEYS = ConfigKeys(
    ConfigKey("host", Kind.TEXT, required=True, pattern=_HOST.pattern,
              expected="the device's or gateway's address or host name, such as "
                       "192.168.10.20",
              doc="The device's or gateway's address or host name (192.168.10.20); drivers "
                  "naming the same host and port are units behind one gateway and share its "
                  "connection."),
    ConfigKey("port", Kind.INT, default=502, minimum=1, maximum=65535,
              expected="a TCP port 1-65535 (Modbus/TCP: 502)", doc="TCP port (502)."),
    ConfigKey("unit", Kind.INT, default=1, minimum=0, maximum=255,
              expected="a unit identifier 0-255 (the slave address behind a gateway; "
                       "often 1 or 255 for a device of its own)",
              doc="Unit identifier: the slave address behind a gateway (often 1 or 255 for a "
                  "device of its own)."),
    ConfigKey("timeout", Kind.DURATION, default=0.2, positive=True,
              expected="a positive time such as 200ms",
              doc="Response timeout per request (200ms)."),
    ConfigKey("retries", Kind.INT, default=1, minimum=0, maximum=10, expected="0-10",
              doc="Further attempts after a timeout or a damaged reply."),
)

#: driver type -> its config keys; the same types, in the same order, as DRIVERS
DRIVER_KEYS: dict[str, ConfigKeys] = {
    "sim": SIM_KEYS,
    "gpio": GPIO_KEYS,
    "mcp23017": MCP23017_KEYS,
    "pcf8574": PCF8574_KEYS,
    "canopen": CANOPEN_KEYS,
    "modbus_rtu": MODBUS_RTU_KEYS,
    "modbus_tcp": MODBUS_TCP_KEYS,
}


@dataclass(frozen=True, slots=True)
class PointTable:
    """One kind of point of a driver type: ``A0``-``A7`` is prefix ``A``, numbers 0-7."""

    prefix: str
    low: int
    high: int
    kind: PointKind = PointKind.BOOL
    #: the only direction it can be bound in (None: either)
    only: Direction | None = None
    #: the refusal of the other direction, after ``DRIVER.POINT``
    wrong_way: str = ""


@dataclass(frozen=True, slots=True)
class PointSpace:
    """The points of a driver type, from its static description (no bus library needed)."""

    #: the words of a refusal, after ``DRIVER.POINT: ``; ``{driver}`` is the driver's name
    words: str
    tables: tuple[PointTable, ...] = ()
    #: any name is a point (sim): IR.../HR... registers, the others bits
    anything: bool = False
    #: a point is bound either as an input or as an output, never both
    one_direction: bool = True
    #: numbers may have leading zeros (``I05``)
    leading_zeros: bool = True

    def check(self, driver: str, point: str, direction: Direction) -> PointKind:
        """The kind of ``point`` bound in ``direction``; PointError if the type lacks it."""
        if self.anything:
            return PointKind.INT if point.upper().startswith(("IR", "HR")) else PointKind.BOOL
        for t in sorted(self.tables, key=lambda t: -len(t.prefix)):
            digits = point[len(t.prefix):]
            if not point.startswith(t.prefix) or not digits.isascii() or not digits.isdigit():
                continue
            if (len(digits) > len(str(t.high)) or not t.low <= int(digits) <= t.high
                    or (not self.leading_zeros and str(int(digits)) != digits)):
                break
            if t.only is not None and t.only is not direction:
                raise PointError(f"{driver}.{point} {t.wrong_way}")
            return t.kind
        raise PointError(f"{driver}.{point}: " + self.words.format(driver=driver))


def _modbus(type_name: str) -> PointSpace:
    """The four tables of a Modbus unit (modbus_rtu, modbus_tcp)."""
    return PointSpace(
        f"a {type_name} point is I<n> (discrete input), Q<n> (coil), IR<n> (input register) "
        "or HR<n> (holding register), n from 0 to 65535",
        (PointTable("I", 0, 0xFFFF, only=Direction.IN,
                    wrong_way="is a discrete input: read-only, it cannot be bound as an output"),
         PointTable("Q", 0, 0xFFFF),
         PointTable("IR", 0, 0xFFFF, PointKind.INT, only=Direction.IN,
                    wrong_way="is an input register: read-only, it cannot be bound as an "
                              "output"),
         PointTable("HR", 0, 0xFFFF, PointKind.INT)))


def _io(high: int, what_in: str, what_out: str) -> tuple[PointTable, PointTable]:
    """An input table ``I`` and an output table ``Q`` of one-way points."""
    return (PointTable("I", 0, high, only=Direction.IN,
                       wrong_way=f"is {what_in}: it cannot be bound as an output"),
            PointTable("Q", 0, high, only=Direction.OUT,
                       wrong_way=f"is {what_out}: it cannot be bound as an input"))


#: driver type -> its points; the same types, in the same order, as DRIVERS
POINTS: dict[str, PointSpace] = {
    "sim": PointSpace("", anything=True, one_direction=False),
    "gpio": PointSpace("a gpio point is a line offset such as {driver}.17",
                       (PointTable("", 0, 1023),), leading_zeros=False),
    "mcp23017": PointSpace("an mcp23017 point is A0-A7 or B0-B7",
                           (PointTable("A", 0, 7), PointTable("B", 0, 7))),
    "pcf8574": PointSpace("a pcf8574 point is P0-P7", (PointTable("P", 0, 7),)),
    "canopen": PointSpace("a canopen point is I0-I63 (0x6000) or Q0-Q63 (0x6200)",
                          _io(63, "an input (0x6000)", "an output (0x6200)")),
    "modbus_rtu": _modbus("modbus_rtu"),
    "modbus_tcp": _modbus("modbus_tcp"),
}


def check_point(type_name: str, driver: str, point: str, direction: Direction,
                bound: dict[str, Direction]) -> PointKind:
    """The kind of ``driver.point`` bound in ``direction``, from the type's description
    (``POINTS``); PointError if the type lacks that point, or if it is bound the other way
    already (``bound``: this driver's points bound so far, updated)."""
    space = POINTS[type_name]
    kind = space.check(driver, point, direction)
    was = bound.setdefault(point, direction)
    if space.one_direction and was is not direction:
        what = "an output" if was is Direction.OUT else "an input"
        raise PointError(f"{driver}.{point} is already bound as {what}: a point of a "
                         f"{type_name} driver is either an input or an output")
    return kind


def check_config(type_name: str, driver: str, config: Mapping[str, Any]) -> dict[str, Any]:
    """Driver ``driver``'s config (``type``, ``on_fault`` aside) as a driver of
    ``type_name`` gets it (``ConfigKeys.validate``); ConfigError naming the key otherwise.
    The plant loader's check, with no bus library imported."""
    keys = DRIVER_KEYS[type_name]
    unknown = sorted(set(config) - set(keys) - {"type", "on_fault"})
    if unknown:
        raise ConfigError(f"driver {driver} ({type_name}): unknown keys {unknown}", unknown[0])
    return keys.validate(config, driver, type_name)


#: bus libraries that are an extra of softplc, not a core dependency: package -> (extra,
#: what installing it needs). gpiod has no wheel for 32-bit ARM on PyPI: pip compiles it.
EXTRAS: dict[str, tuple[str, str]] = {
    "gpiod": ("gpio", "on 32-bit ARM pip compiles it: apt-get install gcc python3-dev first"),
}


def install_hint(extra: str) -> str:
    """The command that adds softplc's extra ``extra`` to the environment running this
    code: this interpreter's pip, given the source tree softplc was installed from (its
    ``direct_url.json``; ``-e`` for an editable install, what scripts/setup.sh makes), or
    this tree when it runs uninstalled. softplc is not published on a package index, so
    never a bare ``softplc[EXTRA]``: pip would fetch whatever owns that name."""
    import json
    import shlex
    import sys
    from importlib import metadata
    from pathlib import Path
    from urllib.parse import unquote, urlsplit

    python = shlex.quote(sys.executable or "python3")
    source, editable = "", False
    try:
        said = json.loads(metadata.distribution("softplc").read_text("direct_url.json") or "")
    except (metadata.PackageNotFoundError, ValueError):
        said = None
    if isinstance(said, dict) and str(said.get("url", "")).startswith("file://"):
        source = unquote(urlsplit(str(said["url"])).path)
        editable = bool((said.get("dir_info") or {}).get("editable"))
    else:
        tree = Path(__file__).resolve().parents[1]
        if (tree / "pyproject.toml").is_file() and (tree / "runtime").is_dir():
            source, editable = str(tree), True
    if not source:
        return (f"{python} -m pip install '/path/to/softplc[{extra}]' (the source tree "
                f"softplc was installed from)")
    return (f"{python} -m pip install {'-e ' if editable else ''}"
            f"{shlex.quote(f'{source}[{extra}]')}")


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
        hint = (f"{install_hint(extra[0])} ({extra[1]})" if extra
                else f"pip install {package}")
        raise DriverImportError(
            f"driver type '{type_name}' needs the Python package '{package}'{missing}: {hint}"
        ) from exc
    cls: type[Driver] = getattr(module, class_name)
    return cls
