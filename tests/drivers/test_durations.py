"""The accepted forms of every reader of a time literal or duration, pinned input by input.

The grammar lives in ``drivers.durations``; each caller keeps its own front (a ``T#``
prefix, a plain number, surrounding spaces) and its own error message. The tables were
taken from the six parsers as they were before they were merged into one home.
"""

from __future__ import annotations

from typing import Any

import pytest

from drivers.config import ConfigError, parse_duration
from drivers.durations import (
    CONFIG,
    LITERAL,
    NS_PER_S,
    format_ns,
    parse_literal,
    parse_ns,
    strip_time_prefix,
)
from drivers.durations import format_ns as format_time
from drivers.durations import parse_literal as parse_time
from runtime.drawing.chronogram import parse_ms
from runtime.engine.instance import coerce
from runtime.engine.names import CommandError, Signal, parse_value
from runtime.errors import Loc, SourceError
from runtime.language import ast as A
from runtime.language.shape import time_value

PARSE_TIME_OK = {'10s': 10000000000, '1m30s': 90000000000, '250ms': 250000000,
    '1d23h': 169200000000000, '1d23h30m20s700ms': 171020700000000, '1.5s': 1500000000,
    '0s': 0, '1_000ms': 1000000000, '1__0s': 10000000000, '_10s': 10000000000,
    '250us': 250000, '100ns': 100, '1us500ns': 1500, '1ms500us': 1500000,
    '1m1s1ms1us1ns': 61001001001, '\u0665s': 5000000000, '10m': 600000000000,
    '2.25h': 8100000000000, '0.1s': 100000000, '0.0001us': 0, '1d': 86400000000000,
    '5h30m': 19800000000000}

PARSE_TIME_BAD = ['1.5', '10', '0', '', ' 10s', '10s ', 'T#10s', 't#10s', 'TIME#1m',
    'time#5ms', 'X#5s', '#5s', 'T#', '10S', '5MS', '1s10m', '10x', '5 ms', '5ms 3s', '5ms3s',
    '1h1h', '.5s', '5.s', '1.s', '250\u00b5s', '\u039cs', '1\u03bcs', '1\u039cs', '-5s', '+5s',
    '1e3ms', '1h30',
    'T# 10s', 'T#10s ', ' T#10s', '1D', 'T#1d', '10.5.5s', '1.2.3', '30m5h']

TIME_VALUE_OK = {'10s': 10000000000, '1m30s': 90000000000, '250ms': 250000000,
    '1d23h': 169200000000000, '1d23h30m20s700ms': 171020700000000, '1.5s': 1500000000,
    '0s': 0, ' 10s': 10000000000, '10s ': 10000000000, 'T#10s': 10000000000,
    't#10s': 10000000000, 'TIME#1m': 60000000000, 'time#5ms': 5000000, '1_000ms': 1000000000,
    '1__0s': 10000000000, '_10s': 10000000000, '250us': 250000, '100ns': 100,
    '1us500ns': 1500, '1ms500us': 1500000, '1m1s1ms1us1ns': 61001001001, '\u0665s': 5000000000,
    '10m': 600000000000, 'T#10s ': 10000000000, ' T#10s': 10000000000, '2.25h': 8100000000000,
    '0.1s': 100000000, '0.0001us': 0, '1d': 86400000000000, 'T#1d': 86400000000000,
    '5h30m': 19800000000000}

TIME_VALUE_BAD = ['1.5', '10', '0', '', 'X#5s', '#5s', 'T#', '10S', '5MS', '1s10m', '10x',
    '5 ms', '5ms 3s', '5ms3s', '1h1h', '.5s', '5.s', '1.s', '250\u00b5s', '\u039cs', '1\u03bcs',
    '1\u039cs',
    '-5s', '+5s', '1e3ms', '1h30', 'T# 10s', '1D', '10.5.5s', '1.2.3', '30m5h']

PARSE_DURATION_OK = {'10s': 10.0, '1m30s': 90.0, '250ms': 0.25, '1.5s': 1.5, '0s': 0.0,
    ' 10s': 10.0, '10s ': 10.0, 'T#10s': 10.0, 't#10s': 10.0, 'TIME#1m': 60.0,
    'time#5ms': 0.005, '10S': 10.0, '5MS': 0.005, '1s10m': 601.0, '1_000ms': 1.0,
    '1__0s': 10.0, '_10s': 10.0, '5 ms': 0.005, '5ms3s': 3.005, '1h1h': 7200.0, '.5s': 0.5,
    '5.s': 5.0, '1.s': 1.0, '250us': 0.00025, '250\u00b5s': 0.00025, '1ms500us': 0.0015,
    '\u0665s': 5.0,
    '10m': 600.0, 'T#10s ': 10.0, ' T#10s': 10.0, '2.25h': 8100.0, '0.1s': 0.1,
    '5h30m': 19800.0, '30m5h': 19800.0}

PARSE_DURATION_BAD = ['1d23h', '1d23h30m20s700ms', '1.5', '10', '0', '', 'X#5s', '#5s', 'T#',
    '10x', '5ms 3s', '100ns', '1us500ns', '1m1s1ms1us1ns', '\u039cs', '-5s', '+5s', '1e3ms',
    '1h30', 'T# 10s', '1d', '1D', 'T#1d', '10.5.5s', '1.2.3']

PARSE_MS_OK = {'10s': 10000.0, '1m30s': 90000.0, '250ms': 250.0, '1d23h': 169200000.0,
    '1d23h30m20s700ms': 171020700.0, '1.5s': 1500.0, '1.5': 1.5, '10': 10.0, '0': 0.0,
    '0s': 0.0, ' 10s': 10000.0, '10s ': 10000.0, 'T#10s': 10000.0, 't#10s': 10000.0,
    'TIME#1m': 60000.0, 'time#5ms': 5.0, '1_000ms': 1000.0, '1__0s': 10000.0, '_10s': 10000.0,
    '250us': 0.25, '100ns': 0.0001, '1us500ns': 0.0015, '1ms500us': 1.5,
    '1m1s1ms1us1ns': 61001.001001, '\u0665s': 5000.0, '10m': 600000.0, 'T#10s ': 10000.0,
    ' T#10s': 10000.0, '2.25h': 8100000.0, '0.1s': 100.0, '0.0001us': 0.0, '1d': 86400000.0,
    'T#1d': 86400000.0, '5h30m': 19800000.0}

PARSE_MS_BAD = ['', 'X#5s', '#5s', 'T#', '10S', '5MS', '1s10m', '10x', '5 ms', '5ms 3s',
    '5ms3s', '1h1h', '.5s', '5.s', '1.s', '250\u00b5s', '\u039cs', '1\u03bcs', '1\u039cs',
    '-5s', '+5s', '1e3ms',
    '1h30', 'T# 10s', '1D', '10.5.5s', '1.2.3', '30m5h']

COERCE_OK = {'10s': 10000000000, '1m30s': 90000000000, '250ms': 250000000,
    '1d23h': 169200000000000, '1d23h30m20s700ms': 171020700000000, '1.5s': 1500000000,
    '0s': 0, 'T#10s': 10000000000, 't#10s': 10000000000, 'TIME#1m': 60000000000,
    'time#5ms': 5000000, 'X#5s': 5000000000, '#5s': 5000000000, '1_000ms': 1000000000,
    '1__0s': 10000000000, '_10s': 10000000000, '250us': 250000, '100ns': 100,
    '1us500ns': 1500, '1ms500us': 1500000, '1m1s1ms1us1ns': 61001001001, '\u0665s': 5000000000,
    '10m': 600000000000, ' T#10s': 10000000000, '2.25h': 8100000000000, '0.1s': 100000000,
    '0.0001us': 0, '1d': 86400000000000, 'T#1d': 86400000000000, '5h30m': 19800000000000}

COERCE_BAD = ['1.5', '10', '0', '', ' 10s', '10s ', 'T#', '10S', '5MS', '1s10m', '10x',
    '5 ms', '5ms 3s', '5ms3s', '1h1h', '.5s', '5.s', '1.s', '250\u00b5s', '\u039cs', '1\u03bcs',
    '1\u039cs',
    '-5s', '+5s', '1e3ms', '1h30', 'T# 10s', 'T#10s ', '1D', '10.5.5s', '1.2.3', '30m5h']

PARSE_VALUE_OK = {'10s': 10000000000, '1m30s': 90000000000, '250ms': 250000000,
    '1d23h': 169200000000000, '1d23h30m20s700ms': 171020700000000, '1.5s': 1500000000,
    '0s': 0, 'T#10s': 10000000000, 't#10s': 10000000000, 'TIME#1m': 60000000000,
    'time#5ms': 5000000, 'X#5s': 5000000000, '#5s': 5000000000, '1_000ms': 1000000000,
    '1__0s': 10000000000, '_10s': 10000000000, '250us': 250000, '100ns': 100,
    '1us500ns': 1500, '1ms500us': 1500000, '1m1s1ms1us1ns': 61001001001, '\u0665s': 5000000000,
    '10m': 600000000000, ' T#10s': 10000000000, '2.25h': 8100000000000, '0.1s': 100000000,
    '0.0001us': 0, '1d': 86400000000000, 'T#1d': 86400000000000, '5h30m': 19800000000000}

PARSE_VALUE_BAD = ['1.5', '10', '0', '', ' 10s', '10s ', 'T#', '10S', '5MS', '1s10m', '10x',
    '5 ms', '5ms 3s', '5ms3s', '1h1h', '.5s', '5.s', '1.s', '250\u00b5s', '\u039cs', '1\u03bcs',
    '1\u039cs',
    '-5s', '+5s', '1e3ms', '1h30', 'T# 10s', 'T#10s ', '1D', '10.5.5s', '1.2.3', '30m5h']


# ------------------------------------------------------------------- the language literal


@pytest.mark.parametrize("text", PARSE_TIME_OK)
def test_literal_accepted(text: str) -> None:
    assert parse_time(text) == PARSE_TIME_OK[text]


@pytest.mark.parametrize("text", PARSE_TIME_BAD)
def test_literal_refused(text: str) -> None:
    assert parse_time(text) is None


@pytest.mark.parametrize("ns", [0, 1, 999, 1_000_000, 1_500_000_000, 90 * 10**9,
                                171_020_700_000_000, -5 * 10**9, 86_400 * 10**9 + 1])
def test_format_round_trips(ns: int) -> None:
    assert parse_time(format_time(ns).lstrip("-")) == abs(ns)


def test_format_examples() -> None:
    assert format_time(0) == "0s"
    assert format_time(90 * 10**9) == "1m30s"
    assert format_time(-250_000_000) == "-250ms"
    assert format_time(86_400 * 10**9 + 1) == "1d1ns"


# ------------------------------------------------------------------ time values in YAML


@pytest.mark.parametrize("text", TIME_VALUE_OK)
def test_yaml_time_accepted(text: str) -> None:
    assert time_value(text, Loc("f.yaml", 1, 1), "x") == TIME_VALUE_OK[text]


@pytest.mark.parametrize("value", [*TIME_VALUE_BAD, 5, 1.5, True, False, None])
def test_yaml_time_refused(value: Any) -> None:
    with pytest.raises(SourceError) as e:
        time_value(value, Loc("f.yaml", 1, 1), "x")
    fixed = value.replace(" ", "") if isinstance(value, str) else ""
    if fixed != value and parse_time(fixed) is not None:  # a valid literal but for its spaces
        assert str(e.value) == (f"f.yaml:1:1: error: expected a time literal without a space "
                                f"between the number and its unit ({fixed}, or T#{fixed}), "
                                f"found '{value}' for x")
        return
    assert str(e.value) == (f"f.yaml:1:1: error: bad time literal '{value}' for x: expected "
                            "e.g. 10s, 250ms, 1m30s or T#10s")


def test_yaml_time_zero() -> None:
    assert time_value(0, Loc("f.yaml", 1, 1), "x") == 0
    assert time_value(0.0, Loc("f.yaml", 1, 1), "x") == 0


# ------------------------------------------------------------------- driver durations


@pytest.mark.parametrize("text", PARSE_DURATION_OK)
def test_driver_duration_accepted(text: str) -> None:
    assert parse_duration(text, "driver d timeout") == PARSE_DURATION_OK[text]


@pytest.mark.parametrize("value", [*PARSE_DURATION_BAD, True, None, [1]])
def test_driver_duration_refused(value: Any) -> None:
    with pytest.raises(ConfigError) as e:
        parse_duration(value, "driver d timeout")
    assert str(e.value) == ("driver d timeout: expected a time such as 5ms or 0.005, found "
                            f"{value!r}")


def test_driver_duration_numbers() -> None:
    assert parse_duration(0, "t") == 0.0
    assert parse_duration(0.005, "t") == 0.005
    assert parse_duration(2, "t") == 2.0
    with pytest.raises(ConfigError, match=r"^t: expected a positive time, found -1$"):
        parse_duration(-1, "t")
    assert parse_duration("0.0001us", "t") == pytest.approx(0.0, abs=1e-9)


# ------------------------------------------------------------- chronogram --from / --to


@pytest.mark.parametrize("text", PARSE_MS_OK)
def test_chronogram_bound_accepted(text: str) -> None:
    assert parse_ms(text, "--to") == PARSE_MS_OK[text]


@pytest.mark.parametrize("text", PARSE_MS_BAD)
def test_chronogram_bound_refused(text: str) -> None:
    with pytest.raises(SourceError) as e:
        parse_ms(text, "--to")
    assert str(e.value) == ("--to:1:1: error: expected a time (2s, 1500ms or a number of ms), "
                            f"found '{text}'")


# ------------------------------------------------------- script / retain values, console


@pytest.mark.parametrize("text", COERCE_OK)
def test_coerce_accepted(text: str) -> None:
    assert coerce(A.Type.TIME, text) == COERCE_OK[text]


@pytest.mark.parametrize("text", COERCE_BAD)
def test_coerce_refused(text: str) -> None:
    with pytest.raises(ValueError) as e:
        coerce(A.Type.TIME, text)
    assert str(e.value) == f"expected a time like 10s, found '{text}'"


def test_coerce_numbers() -> None:
    assert coerce(A.Type.TIME, 5_000) == 5_000
    assert coerce(A.Type.TIME, 2.7) == 2


def _time_name() -> Signal:
    return Signal("T1", A.Type.TIME, lambda img: 0, "memory")


@pytest.mark.parametrize("text", PARSE_VALUE_OK)
def test_console_value_accepted(text: str) -> None:
    assert parse_value(_time_name(), text) == PARSE_VALUE_OK[text]


@pytest.mark.parametrize("text", PARSE_VALUE_BAD)
def test_console_value_refused(text: str) -> None:
    with pytest.raises(CommandError) as e:
        parse_value(_time_name(), text)
    assert str(e.value) == (f"bad value '{text}' for T1: expected a time like 5s, 250ms or "
                            "T#1m30s")


# ------------------------------------------------------------------- the module itself


def test_greek_mu_reads_as_micro() -> None:
    """``μs`` (Greek mu, what most keyboards type) and ``Μs`` read as ``µs`` in configs (they
    used to fail with a KeyError inside parse_duration)."""
    assert parse_duration("250\u03bcs", "t") == 0.00025
    assert parse_duration("250\u039cs", "t") == 0.00025
    assert parse_ns("250\u03bcs", CONFIG) == 250_000
    assert parse_literal("250\u03bcs") is None


def test_grammars_differ_only_where_documented() -> None:
    assert parse_ns("1s10m", CONFIG) == 601 * NS_PER_S
    assert parse_ns("1s10m", LITERAL) is None
    assert parse_ns("1d", CONFIG) is None
    assert strip_time_prefix("time#5s") == "5s"
    assert strip_time_prefix("X#5s") == "X#5s"
    assert format_ns(61_001_001_001) == "1m1s1ms1us1ns"
