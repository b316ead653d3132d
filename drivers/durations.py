"""Durations written as text (``10s``, ``1m30s``, ``250ms``, ``T#10s``): the one parser and
the one formatter, in nanoseconds.

It lives in ``drivers`` (the bottom layer, which imports nothing of ``runtime``) because
every part reads times: the language's literals, the YAML files, the console, the
chronogram's bounds and the drivers' configs. It has no dependency and no state.

Two grammars, one scanner:

- ``LITERAL``, the language's time literal (language.md): a number (``10``, ``1.5``)
  followed by a unit, units in order ``d h m s ms us ns``, each at most once, case as
  written; ``_`` may separate digits anywhere. ``1d23h30m20s700ms``.
- ``CONFIG``, a duration in a driver config: units ``h m s ms us µs`` in any order and any
  case, a number may be ``.5`` or ``5.``, spaces may sit between a number and its unit;
  ``_`` is dropped. ``5 ms``, ``1s500ms``, ``250µs``.

A ``T#``/``TIME#`` prefix (IEC 61131-3) is not part of either grammar: each caller decides
whether it accepts one (``strip_time_prefix``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from decimal import Decimal

#: nanoseconds per unit
NS_PER_UNIT: dict[str, int] = {
    "d": 86_400_000_000_000, "h": 3_600_000_000_000, "m": 60_000_000_000,
    "s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "µs": 1_000, "ns": 1}
#: the units of a literal, largest first: the order they must be written in
LITERAL_UNITS = ("d", "h", "m", "s", "ms", "us", "ns")
#: nanoseconds per second
NS_PER_S = 1_000_000_000
#: the longest duration a driver's config takes, ns (64-bit: about 292 years)
MAX_NS = 2**63 - 1


@dataclass(frozen=True, slots=True)
class Grammar:
    """How one number-and-unit part is written, and whether units must come in order."""

    part: re.Pattern[str]
    in_order: bool


#: the language's time literal
LITERAL = Grammar(re.compile(r"(\d+(?:\.\d+)?)(ms|us|ns|d|h|m|s)"), in_order=True)
#: a duration in a driver config (also matches the Greek small mu, read as the micro sign)
CONFIG = Grammar(re.compile(r"(\d+(?:\.\d*)?|\.\d+)\s*(us|µs|ms|s|m|h)", re.IGNORECASE),
                 in_order=False)
#: a candidate time literal inside other text (``for 1s234ms567us``): whole words of
#: integer parts only; ``parse_literal`` of a match says whether it is one
LITERAL_IN_TEXT = re.compile(r"\b(?:\d+(?:d|h|ms|m|s|us|ns))+\b")


def _unit(text: str) -> str:
    unit = text.lower()
    return "us" if unit[0] in "µμ" else unit  # µ micro sign, μ Greek mu (IGNORECASE: Μ)


def parse_ns(text: str, grammar: Grammar = LITERAL) -> int | None:
    """``text`` -> nanoseconds, or None if it is not a duration of ``grammar``.

    ``_`` is dropped first. Each part is rounded to the nanosecond on its own. The total
    is not bounded (a number of 400 digits is exact): a caller refuses what is beyond its
    range (``MAX_NS``, 64-bit nanoseconds, for a driver's config).
    """
    t = text.replace("_", "")
    pos, total, last = 0, 0, -1
    while pos < len(t):
        m = grammar.part.match(t, pos)
        if not m:
            return None
        unit = _unit(m.group(2))
        if grammar.in_order:
            idx = LITERAL_UNITS.index(unit)
            if idx <= last:
                return None
            last = idx
        part = float(m.group(1)) * NS_PER_UNIT[unit]
        if math.isfinite(part):
            total += round(part)
        else:  # 400 digits: float() is infinite, the exact value is the caller's to judge
            total += round(Decimal(m.group(1)) * NS_PER_UNIT[unit])
        pos = m.end()
    return total if pos > 0 else None


def parse_literal(text: str) -> int | None:
    """The language's time literal ``1d23h30m20s700ms`` -> nanoseconds, or None."""
    return parse_ns(text, LITERAL)


def strip_time_prefix(text: str) -> str:
    """``T#10s``/``time#10s`` -> ``10s``; other text unchanged."""
    if text.upper().startswith(("T#", "TIME#")):
        return text.split("#", 1)[1]
    return text


def format_ns(ns: int) -> str:
    """Nanoseconds -> the shortest literal (``1m30s``; ``0s``; ``-250ms``)."""
    if ns == 0:
        return "0s"
    out, rest = [], abs(ns)
    for unit in LITERAL_UNITS:
        q, rest = divmod(rest, NS_PER_UNIT[unit])
        if q:
            out.append(f"{q}{unit}")
    return ("-" if ns < 0 else "") + "".join(out)
