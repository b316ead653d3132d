"""Driver config values are checked once, from their declaration (drivers.registry):
every bound and choice a key declares is where the driver class itself starts refusing,
and the refusals keep their words.

The drivers are constructed, never opened: no bus is touched (the bus libraries are
imported, nothing more).
"""

from __future__ import annotations

import re
from typing import Any

import pytest

from drivers.base import Driver
from drivers.canopen_io import CanopenDriver
from drivers.config import ConfigError, ConfigKey, Kind
from drivers.modbus_rtu import ModbusRtuDriver
from drivers.registry import DRIVER_KEYS, GPIO_LABEL, MODBUS_RTU_KEYS, driver_class
from drivers.serial_line import SerialSettings
from tests.drivers.test_config_keys import resolve, schema_of

NAME = "d"


def valid_value(key: ConfigKey) -> Any:
    """A value the declaration accepts for ``key`` (for the required keys)."""
    if key.kind in (Kind.INT, Kind.I2C_ADDRESS):
        return key.minimum if key.minimum is not None else 1
    if key.kind is Kind.TEXT:
        if key.pattern:
            return "/dev/x" if _is_path(key) else "localhost"
        return "x" * max(1, key.minimum or 0)
    if key.kind is Kind.CHOICE:
        return key.choices[0]
    raise AssertionError(f"no valid value for required {key}")  # pragma: no cover


def _is_path(key: ConfigKey) -> bool:
    """A TEXT key whose pattern takes a device path (else a host)."""
    return key.pattern is not None and re.fullmatch(key.pattern, "/dev/x") is not None


def minimal_config(type_name: str) -> dict[str, Any]:
    """Every required key of ``type_name``, with a valid value."""
    return {k.name: valid_value(k) for k in DRIVER_KEYS[type_name].values() if k.required}


def make(type_name: str, **cfg: Any) -> Driver:
    return driver_class(type_name)(NAME, {**minimal_config(type_name), **cfg})


def edges(key: ConfigKey) -> list[tuple[Any, bool, Any]]:
    """(value, accepted?, the value the driver gets) just inside and just outside every
    bound and choice of ``key``; [] for a key that declares none."""
    out: list[tuple[Any, bool, Any]] = []
    low, high = key.minimum, key.maximum
    if key.kind in (Kind.INT, Kind.I2C_ADDRESS):
        for inside, outside in ((low, None if low is None else low - 1),
                                (high, None if high is None else high + 1)):
            if inside is None or outside is None:
                continue
            out += [(inside, True, inside), (outside, False, None)]
            if key.kind is Kind.I2C_ADDRESS:  # "0x20" as text reads as 0x20
                out += [(f"0x{inside:02x}", True, inside), (f"0x{outside:02x}", False, None)]
    elif key.kind is Kind.TEXT:
        if key.pattern is not None and _is_path(key):  # a device: /dev/x, not "/dev/x y"
            out += [("/dev/x", True, "/dev/x"), ("/dev/x y", False, None), ("", False, None)]
            if key.pattern.endswith(GPIO_LABEL):  # or a GPIO chip's label, 1-31 characters
                out += [("x", True, "x"), ("a b", True, "a b"), ("x" * 31, True, "x" * 31),
                        ("x" * 32, False, None), (" x", False, None), ("x ", False, None),
                        ("gpiochip0", False, None), ("gpiochip", True, "gpiochip")]
            else:
                out += [("x", False, None)]
        elif key.pattern is not None:  # a host: a name or an address, no space, no path
            out += [("plc-7.local", True, "plc-7.local"), ("10.0.0.2", True, "10.0.0.2"),
                    ("fe80::1", True, "fe80::1"), ("a b", False, None),
                    ("/dev/x", False, None), ("", False, None)]
        if low is not None:
            out += [("x" * low, True, "x" * low), ("x" * (low - 1), False, None)]
        if high is not None:
            out += [("x" * high, True, "x" * high), ("x" * (high + 1), False, None)]
    elif key.kind is Kind.CHOICE:
        for choice in key.choices:
            out.append((choice, True, choice))
            if isinstance(choice, str):
                out.append((choice + "x", False, None))
                if key.any_case:
                    out.append((choice.lower(), True, choice))
                else:
                    out.append((choice.upper() if choice.islower() else choice.lower(), False,
                                None))
        for alias, choice in key.aliases:
            out += [(alias, True, choice), (alias.lower(), key.any_case, choice)]
        numbers = [c for c in key.choices if isinstance(c, int) and not isinstance(c, bool)]
        if numbers:
            out += [(min(numbers) - 1, False, None), (max(numbers) + 1, False, None),
                    (True, False, None)]
    elif key.kind is Kind.DURATION:
        if key.positive:
            out += [(1e-6, True, 1e-6), ("1us", True, 1e-6), (0, False, None),
                    ("0ms", False, None)]
        else:
            out += [(0, True, 0.0), ("0ms", True, 0.0), (-1e-6, False, None)]
    return out


CASES = [(t, k.name, value, accepted, got)
         for t, keys in DRIVER_KEYS.items() for k in keys.values()
         for value, accepted, got in edges(k)]


def test_every_bound_and_choice_is_covered() -> None:
    """Each key with a range, a length, choices or a time is in CASES."""
    covered = {(t, k) for t, k, *_ in CASES}
    for t, keys in DRIVER_KEYS.items():
        for k in keys.values():
            ranged = (k.minimum is not None or k.maximum is not None or k.choices
                      or k.pattern is not None)
            if ranged or k.kind is Kind.DURATION:
                assert (t, k.name) in covered, (t, k.name)
    assert len(CASES) > 60


@pytest.mark.parametrize("type_name, key_name, value, accepted, got", CASES)
def test_driver_refuses_just_outside_its_declaration(type_name: str, key_name: str, value: Any,
                                                     accepted: bool, got: Any) -> None:
    key = DRIVER_KEYS[type_name][key_name]
    if accepted:
        d = make(type_name, **{key_name: value})
        assert d.params[key_name] == got
        assert type(d.params[key_name]) is type(got)
        return
    with pytest.raises(ConfigError) as e:
        make(type_name, **{key_name: value})
    if key.kind is Kind.DURATION and not key.positive:  # below 0: parse_duration's words
        assert str(e.value) == (f"driver {NAME} ({type_name}): {key_name}: expected a positive "
                                f"time, found "
                                f"{value!r}")
    else:
        assert str(e.value) == str(key.refusal(value, NAME, type_name))


@pytest.mark.parametrize("type_name", list(DRIVER_KEYS))
def test_absent_keys_take_their_declared_defaults(type_name: str) -> None:
    d = make(type_name)
    for key in DRIVER_KEYS[type_name].values():
        if key.required:
            continue
        want = None if key.default is None else key.check(key.default, NAME, type_name)
        assert d.params[key.name] == want, key.name


@pytest.mark.parametrize("type_name", list(DRIVER_KEYS))
def test_a_required_key_missing_is_refused(type_name: str) -> None:
    for key in DRIVER_KEYS[type_name].values():
        if not key.required:
            continue
        cfg = minimal_config(type_name)
        del cfg[key.name]
        with pytest.raises(ConfigError) as e:
            driver_class(type_name)(NAME, cfg)
        assert str(e.value) == str(key.refusal(None, NAME, type_name))


def test_modbus_settings_use_the_declared_defaults() -> None:
    d = make("modbus_rtu")
    assert isinstance(d, ModbusRtuDriver)
    assert (d.cfg.baudrate, d.cfg.parity, d.cfg.stopbits, d.cfg.unit, d.cfg.retries,
            d.cfg.timeout_s) == (19200, "N", 1, 1, 2, 0.1)
    assert SerialSettings("/dev/x") == SerialSettings(
        "/dev/x", MODBUS_RTU_KEYS["baudrate"].default, MODBUS_RTU_KEYS["parity"].default,
        MODBUS_RTU_KEYS["stopbits"].default)


def test_optional_keys_without_default_may_be_null() -> None:
    d = make("canopen", sync=None, bitrate=None, eds=None, pdo=None)
    assert isinstance(d, CanopenDriver)
    assert d.params["sync"] is None and d.cfg.sync_s is None and d.cfg.tpdos is None


def test_text_length_matches_the_schema() -> None:
    for type_name, keys in DRIVER_KEYS.items():
        for key in keys.values():
            if key.kind is Kind.TEXT:
                node = resolve(schema_of(type_name)["properties"][key.name])
                assert node.get("minLength") == key.minimum, (type_name, key.name)
                assert node.get("maxLength") == key.maximum, (type_name, key.name)


MCP_WORDS = ("driver d (mcp23017): address: expected an MCP23017 address from 0x20 to 0x27 "
             "(pins A2 A1 A0), found ")
PCF_WORDS = ("driver d (pcf8574): address: expected a PCF8574 address from 0x20 to 0x27 or a "
             "PCF8574A address from 0x38 to 0x3f (pins A2 A1 A0), found ")

# The words of every refusal, as the drivers said them when each checked its own values.
MESSAGES = [
    ("gpio", {"bias": "up"},
     "driver d (gpio): bias 'up': expected one of pull_up, pull_down, none"),
    ("gpio", {"bias": None},
     "driver d (gpio): bias 'None': expected one of pull_up, pull_down, none"),
    ("gpio", {"debounce": "5 parsecs"},
     "driver d (gpio): debounce: expected a time such as 5ms or 0.005, found '5 parsecs'"),
    ("gpio", {"debounce": -1}, "driver d (gpio): debounce: expected a positive time, found -1"),
    ("mcp23017", {"address": 32},
     "driver d (mcp23017): bus: expected the I2C bus number (1 for /dev/i2c-1), found None"),
    ("mcp23017", {"bus": -1, "address": 32},
     "driver d (mcp23017): bus: expected the I2C bus number (1 for /dev/i2c-1), found -1"),
    ("mcp23017", {"bus": "one", "address": 32},
     "driver d (mcp23017): bus: expected the I2C bus number (1 for /dev/i2c-1), found 'one'"),
    ("mcp23017", {"bus": 1},
     MCP_WORDS + "None"),
    ("mcp23017", {"bus": 1, "address": 300},
     MCP_WORDS + "300"),
    ("mcp23017", {"bus": 1, "address": "0x78"},
     MCP_WORDS + "'0x78'"),
    ("mcp23017", {"bus": 1, "address": "zz"},
     MCP_WORDS + "'zz'"),
    ("mcp23017", {"bus": 1, "address": 32, "pull_up": "yes"},
     "driver d (mcp23017): pull_up: expected true or false, found 'yes'"),
    ("pcf8574", {"bus": 1, "address": 120},
     PCF_WORDS + "120"),
    ("pcf8574", {"bus": True, "address": 56},
     "driver d (pcf8574): bus: expected the I2C bus number (1 for /dev/i2c-1), found True"),
    ("canopen", {}, "driver d (canopen): node: expected a node-ID 1-127, found None"),
    ("canopen", {"node": 128}, "driver d (canopen): node: expected a node-ID 1-127, found 128"),
    ("canopen", {"node": True},
     "driver d (canopen): node: expected a node-ID 1-127, found True"),
    ("canopen", {"node": 5, "bitrate": "fast"},
     "driver d (canopen): bitrate: expected a CAN bit rate: 10000, 20000, 50000, 100000, "
     "125000, 250000, 500000, 800000, 1000000, found 'fast'"),
    ("canopen", {"node": 5, "heartbeat": "soon"},
     "driver d (canopen): heartbeat: expected a time such as 5ms or 0.005, found 'soon'"),
    ("canopen", {"node": 5, "heartbeat": "0ms"},
     "driver d (canopen): heartbeat: expected a positive consumer timeout such as 500ms, "
     "at most 262s (the node's heartbeat is a quarter of it, in 16-bit ms), found '0ms'"),
    ("canopen", {"node": 5, "sync": 0},
     "driver d (canopen): sync: expected a positive SYNC period such as 10ms, at most "
     "4294s, found 0"),
    ("canopen", {"node": 5, "pdo": [1]},
     "driver d (canopen): pdo: expected a mapping such as {tpdo1: ['6000:1'], "
     "rpdo1: ['6200:1']}"),
    ("canopen", {"node": 5, "pdo": {"tpdo9": []}},
     "driver d (canopen): pdo: 'tpdo9': expected tpdo1-tpdo4 or rpdo1-rpdo4 with a list of "
     "mapped objects such as '6000:1'"),
    ("canopen", {"node": 5, "pdo": {"tpdo1": ["6000"]}},
     "driver d (canopen): pdo tpdo1: '6000': expected INDEX:SUB in hex, with /BITS if not 8 "
     "(e.g. 6000:1, 2000:0/16)"),
    ("modbus_rtu", {},
     "driver d (modbus_rtu): port: expected a serial device such as /dev/ttyUSB0 (its full "
     "path), found None"),
    ("modbus_rtu", {"port": 5},
     "driver d (modbus_rtu): port: expected a serial device such as /dev/ttyUSB0 (its full "
     "path), found 5"),
    ("modbus_rtu", {"port": "/dev/x", "unit": 248},
     "driver d (modbus_rtu): unit: expected a slave address 1-247, found 248"),
    ("modbus_rtu", {"port": "/dev/x", "baudrate": "fast"},
     "driver d (modbus_rtu): baudrate: expected a standard baud rate such as 9600, 19200 or "
     "115200 (50 to 4000000), found 'fast'"),
    ("modbus_rtu", {"port": "/dev/x", "parity": "X"},
     "driver d (modbus_rtu): parity: expected N, E or O, found 'X'"),
    ("modbus_rtu", {"port": "/dev/x", "stopbits": 3},
     "driver d (modbus_rtu): stopbits: expected 1 or 2, found 3"),
    ("modbus_rtu", {"port": "/dev/x", "timeout": "fast"},
     "driver d (modbus_rtu): timeout: expected a time such as 5ms or 0.005, found 'fast'"),
    ("modbus_rtu", {"port": "/dev/x", "timeout": 0},
     "driver d (modbus_rtu): timeout: expected a positive time such as 100ms, found 0"),
    ("modbus_rtu", {"port": "/dev/x", "retries": 11},
     "driver d (modbus_rtu): retries: expected 0-10, found 11"),
    ("sim", {"colour": 1}, "driver d (sim): unknown keys ['colour']"),
    # keys that declare no words of their own: the kind and range say them
    ("gpio", {"chip": 5}, "driver d (gpio): chip: expected a GPIO chip: its character device "
     "such as /dev/gpiochip0 (the full path) or its label such as pinctrl-rp1 (gpiodetect "
     "lists both), found 5"),
    ("canopen", {"node": 5, "channel": 1.5},
     "driver d (canopen): channel: expected text or an integer, found 1.5"),
]


@pytest.mark.parametrize("type_name, cfg, message", MESSAGES)
def test_refusals_keep_their_words(type_name: str, cfg: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError) as e:
        driver_class(type_name)(NAME, cfg)
    assert str(e.value) == message


def test_described_from_kind_and_range() -> None:
    assert ConfigKey("n", Kind.INT, minimum=1, maximum=9).describe() == "an integer from 1 to 9"
    assert ConfigKey("n", Kind.INT, minimum=0).describe() == "an integer of at least 0"
    assert ConfigKey("n", Kind.INT, maximum=9).describe() == "an integer of at most 9"
    assert ConfigKey("a", Kind.I2C_ADDRESS, minimum=8, maximum=0x77).describe() == (
        "an I2C address from 0x08 to 0x77")
    assert ConfigKey("c", Kind.CHOICE, choices=(1, 2)).describe() == "one of 1, 2"
    assert ConfigKey("t", Kind.TEXT, minimum=1).describe() == "non-empty text"
    assert ConfigKey("m", Kind.MAPPING).describe() == "a mapping"
