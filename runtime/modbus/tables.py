"""The Modbus server's four tables, built from the plant's map (``ModbusDef.points``,
runtime/language/modbusconf.py) and refreshed from each frame of the feed; values to and
from registers.

A bit is 0 or 1. A number is carried as its map entry's type: INT (signed 16 bits), UINT
(unsigned 16 bits), DINT and UDINT (32 bits, two registers), REAL (IEEE 754 single, two
registers), TIME (milliseconds, unsigned 32 bits, two registers); the two registers of a
32-bit value in the section's ``words`` order (``high_first``, Modbus' big-endian order,
or ``low_first``). A value the type cannot hold is sent as the nearest it can (an int of
70000 as INT is 32767), and said once in the log while it lasts (``clipped``). A write is
decoded the other way; a REAL that is no finite number is refused (exception 3)."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.modbus_frame import ILLEGAL_DATA_ADDRESS, ILLEGAL_DATA_VALUE, RequestError
from runtime.language.model import ModbusPoint

#: the bounds of each integer type
BOUNDS = {"INT": (-0x8000, 0x7FFF), "UINT": (0, 0xFFFF), "DINT": (-0x80000000, 0x7FFFFFFF),
          "UDINT": (0, 0xFFFFFFFF), "TIME": (0, 0xFFFFFFFF)}
#: the largest float32
FLOAT32_MAX = 3.4028234663852886e38
NS_PER_MS = 1_000_000


def encode(pt: ModbusPoint, value: Any, high_first: bool = True,
           time_name: bool = False) -> tuple[list[int], bool]:
    """``value`` (as the feed gives it: a time in ns) as ``pt``'s registers (a bit: [0 or
    1]), and whether it had to be clipped. ``time_name``: the plant name is a TIME (sent
    in ms whatever its wire type)."""
    if pt.type == "BOOL":
        return [1 if value else 0], False
    if pt.type == "REAL":
        v = float(value)
        clipped = math.isfinite(v) and abs(v) > FLOAT32_MAX
        if clipped:
            v = math.copysign(FLOAT32_MAX, v)
        hi, lo = struct.unpack(">HH", struct.pack(">f", v))
        return ([hi, lo] if high_first else [lo, hi]), clipped
    n = value
    if time_name or pt.type == "TIME":
        n = round(value / NS_PER_MS)
    if isinstance(n, float):
        n = round(n) if math.isfinite(n) else 0
    n = int(n)
    low, high = BOUNDS[pt.type]
    clipped = not low <= n <= high
    n = min(max(n, low), high)
    if pt.words == 1:
        return [n & 0xFFFF], clipped
    n &= 0xFFFFFFFF
    hi, lo = n >> 16, n & 0xFFFF
    return ([hi, lo] if high_first else [lo, hi]), clipped


def decode(pt: ModbusPoint, regs: list[int], high_first: bool = True,
           time_name: bool = False) -> Any:
    """``pt``'s registers (a bit: [0 or 1]) as the value to write (a time in ns);
    RequestError(3) for a REAL that is no finite number."""
    if pt.type == "BOOL":
        return bool(regs[0])
    if pt.words == 1:
        n = regs[0]
        if pt.type == "INT" and n >= 0x8000:
            n -= 0x10000
        return n
    hi, lo = (regs[0], regs[1]) if high_first else (regs[1], regs[0])
    if pt.type == "REAL":
        v = struct.unpack(">f", struct.pack(">HH", hi, lo))[0]
        if not math.isfinite(v):
            raise RequestError(ILLEGAL_DATA_VALUE, f"{pt.name}: {v} is not a finite number")
        return v
    n = hi << 16 | lo
    if pt.type == "DINT" and n >= 0x80000000:
        n -= 0x100000000
    if time_name or pt.type == "TIME":
        return n * NS_PER_MS
    return n


@dataclass(frozen=True, slots=True)
class Write:
    """One name a write request sets, and its value (a time in ns)."""

    name: str
    value: Any


class Tables:
    """The coils (``Q``), discrete inputs (``I``), input registers (``IR``) and holding
    registers (``HR``) of the map. A table's size is its highest mapped address + 1: a
    read inside it is answered (an address no name has reads 0), past it refused (2)."""

    def __init__(self, points: list[ModbusPoint], words: str = "high_first",
                 times: set[str] | None = None) -> None:
        self.points = points
        self.high_first = words == "high_first"
        #: the names whose plant type is TIME (sent in ms)
        self.times = times or set()
        self.size: dict[str, int] = {t: 0 for t in ("Q", "I", "IR", "HR")}
        #: table -> address -> (point, its register's index)
        self.at: dict[str, dict[int, tuple[ModbusPoint, int]]] = {t: {} for t in self.size}
        for pt in points:
            for k in range(max(1, pt.words)):
                self.at[pt.table][pt.address + k] = (pt, k)
            self.size[pt.table] = max(self.size[pt.table], pt.address + max(1, pt.words))
        self.values: dict[str, list[int]] = {t: [0] * n for t, n in self.size.items()}
        #: the names sent clipped in the last refresh
        self.clipped: set[str] = set()

    def refresh(self, get: Callable[[str], Any]) -> list[tuple[str, Any, bool]]:
        """Every mapped name's value from ``get`` (the feed's last frame); returns the names
        whose clipping started or ended, (name, value, clipped now), for one log line
        each."""
        changes: list[tuple[str, Any, bool]] = []
        for pt in self.points:
            value = get(pt.name)
            regs, clipped = encode(pt, value, self.high_first, pt.name in self.times)
            self.values[pt.table][pt.address:pt.address + len(regs)] = regs
            if clipped != (pt.name in self.clipped):
                (self.clipped.add if clipped else self.clipped.discard)(pt.name)
                changes.append((pt.name, value, clipped))
        return changes

    def read(self, table: str, address: int, count: int) -> list[int]:
        """``count`` items from ``address``; RequestError(2) past the table's size."""
        if address + count > self.size[table]:
            raise RequestError(ILLEGAL_DATA_ADDRESS, f"{table}{address}-"
                               f"{table}{address + count - 1}: the map's {table} end at "
                               f"{table}{self.size[table] - 1}" if self.size[table] else
                               f"{table}{address}: the map has no {table}")
        return self.values[table][address:address + count]

    def writes(self, table: str, address: int, values: list[int],
               writable: Callable[[str], bool]) -> list[Write]:
        """What writing ``values`` from ``address`` sets; RequestError(2) for an address no
        name has, a name not writable (``writable``), or half of a two-register value,
        and nothing written."""
        at = self.at[table]
        out: list[Write] = []
        k = 0
        while k < len(values):
            a = address + k
            hit = at.get(a)
            if hit is None:
                raise RequestError(ILLEGAL_DATA_ADDRESS, f"{table}{a}: no name there")
            pt, index = hit
            n = max(1, pt.words)
            if index != 0 or k + n > len(values):
                raise RequestError(ILLEGAL_DATA_ADDRESS, f"{table}{a}: half of {pt.name} "
                                   f"({pt.type} at {table}{pt.address}-{table}"
                                   f"{pt.address + n - 1}): write both registers")
            if not writable(pt.name):
                raise RequestError(ILLEGAL_DATA_ADDRESS, f"{table}{a}: {pt.name} is not "
                                   "writable (modbus: writable)")
            out.append(Write(pt.name, decode(pt, values[k:k + n], self.high_first,
                                             pt.name in self.times)))
            k += n
        return out
