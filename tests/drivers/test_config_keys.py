"""The driver config keys are declared once (drivers.registry): the driver classes, the
plant loader and configs/schema/plant.schema.json all agree with the declaration."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from drivers.config import ConfigKey, ConfigKeys, Kind
from drivers.registry import DRIVER_KEYS, DRIVER_WORDS, DRIVERS

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = json.loads((ROOT / "configs" / "schema" / "plant.schema.json").read_text("utf-8"))
#: keys every driver takes, handled by Driver itself
COMMON = {"type", "on_fault"}


def schema_of(type_name: str) -> dict[str, Any]:
    """The ``then`` branch of the driver schema for ``type: type_name``."""
    for branch in SCHEMA["$defs"]["driver"]["allOf"]:
        if branch["if"]["properties"]["type"]["const"] == type_name:
            then: dict[str, Any] = branch["then"]
            return then
    raise AssertionError(f"no schema branch for driver type {type_name}")


def resolve(node: dict[str, Any]) -> dict[str, Any]:
    ref = node.get("$ref")
    if ref is None:
        return node
    assert ref.startswith("#/$defs/"), ref
    target: dict[str, Any] = SCHEMA["$defs"][ref.removeprefix("#/$defs/")]
    return target


def test_the_same_types_everywhere() -> None:
    assert list(DRIVER_KEYS) == list(DRIVERS) == list(DRIVER_WORDS)
    assert SCHEMA["$defs"]["driver"]["properties"]["type"]["enum"] == list(DRIVER_KEYS)


@pytest.mark.parametrize("type_name", list(DRIVER_KEYS))
def test_schema_lists_exactly_the_declared_keys(type_name: str) -> None:
    then = schema_of(type_name)
    assert then["additionalProperties"] is False
    assert set(then["properties"]) - COMMON == set(DRIVER_KEYS[type_name])
    required = {k.name for k in DRIVER_KEYS[type_name].values() if k.required}
    assert set(then.get("required", [])) == required


def _check_kind(key: ConfigKey, prop: dict[str, Any]) -> None:
    node = resolve(prop)
    if key.kind is Kind.TEXT:
        assert node["type"] == "string"
    elif key.kind is Kind.INT:
        assert node["type"] == "integer"
        low = node.get("minimum", node.get("exclusiveMinimum", -1) + 1
                       if "exclusiveMinimum" in node else None)
        assert low == key.minimum
        assert node.get("maximum") == key.maximum
    elif key.kind is Kind.BOOL:
        assert node["type"] == "boolean"
    elif key.kind is Kind.DURATION:
        assert prop["$ref"] == "#/$defs/duration"
    elif key.kind is Kind.CHOICE:
        enum = node["enum"]
        assert ({v.upper() for v in enum} if key.any_case else set(enum)) == set(key.choices)
    elif key.kind is Kind.I2C_ADDRESS:
        assert prop["$ref"].endswith("Address")
        as_int = [(a["minimum"], a["maximum"]) for a in node["anyOf"]
                  if a.get("type") == "integer"]
        assert as_int == list(key.ranges or [(key.minimum, key.maximum)])
    elif key.kind is Kind.TEXT_OR_INT:
        assert sorted(node["type"]) == ["integer", "string"]
    elif key.kind is Kind.MAPPING:
        assert node["type"] == "object"
    else:  # pragma: no cover - a new Kind needs a rule here
        raise AssertionError(key.kind)


@pytest.mark.parametrize("type_name, key_name", [(t, k) for t, keys in DRIVER_KEYS.items()
                                                 for k in keys])
def test_schema_kind_default_and_range_match(type_name: str, key_name: str) -> None:
    key = DRIVER_KEYS[type_name][key_name]
    prop = schema_of(type_name)["properties"][key_name]
    _check_kind(key, prop)
    if "default" in prop:
        assert prop["default"] == key.default
    elif key.kind is not Kind.DURATION:  # the schema gives no default for times
        assert key.default is None


def test_keys_keep_their_order_and_defaults() -> None:
    keys = ConfigKeys(ConfigKey("b", Kind.INT, default=3), ConfigKey("a", Kind.TEXT))
    assert list(keys) == ["b", "a"]
    assert keys.value({}, "b") == 3
    assert keys.value({"b": 4}, "b") == 4
    assert keys.value({}, "a") is None


def test_declarations_load_without_bus_libraries() -> None:
    """The plant loader reads them on a machine without smbus2, gpiod, canopen, pyserial."""
    import subprocess
    import sys

    code = ("import sys\n"
            "for m in ('smbus2', 'gpiod', 'canopen', 'can', 'serial'):\n"
            "    sys.modules[m] = None\n"
            "import drivers.registry, runtime.language.plantfile\n"
            "assert 'drivers.modbus_rtu' not in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


#: texts the path and label patterns of the config keys are tried on
PATTERN_SAMPLES = ["/dev/gpiochip0", "/dev/ttyUSB0", "/dev/x y", "/", "", "x", "gpiochip0",
                   "gpiochip", "pinctrl-rp1", "INT3450:00", "a b", " x", "x ", "x" * 31,
                   "x" * 32, "x\ty", "x\x7fy", "vcan0"]


@pytest.mark.parametrize("type_name, key_name", [
    (t, k.name) for t, keys in DRIVER_KEYS.items() for k in keys.values() if k.pattern])
def test_schema_patterns_accept_what_the_keys_accept(type_name: str, key_name: str) -> None:
    key = DRIVER_KEYS[type_name][key_name]
    node = resolve(schema_of(type_name)["properties"][key_name])
    for text in PATTERN_SAMPLES:
        assert (re.search(node["pattern"], text) is not None) == \
            (re.fullmatch(key.pattern or "", text) is not None), (key_name, text)
