"""IEC 61131-3 located addresses (``%IX0.3``, ``%QW2``, ``%MD10``): what a plant's binding
may give as ``at:`` (its signal's address in the IEC sense, as Beremiz, CODESYS and OpenPLC
programs locate their I/O), and what the Modbus server's map follows (docs/modbus.md).

Only the forms a Modbus map can use are read: an area (``I`` input, ``Q`` output, ``M``
memory), a size (``X`` a bit, with its ``.bit`` 0-7; ``W`` a 16-bit word; ``D`` a 32-bit
double word) and a number, in one level (``%IX0.3``, not ``%IX1.0.3``)."""

from __future__ import annotations

import re
from dataclasses import dataclass

_LOCATED = re.compile(r"^%([IQM])([XWD])(\d{1,5})(?:\.(\d{1,2}))?$")
#: a binding's ``at:`` as editors check it (an input's or output's: %I or %Q; the loader's
#: check is ``parse_located``'s, then the binding's direction and type)
BINDING_AT_PATTERN = r"^%[IQiq][XWDxwd][0-9]{1,5}(\.[0-7])?$"


@dataclass(frozen=True, slots=True)
class Located:
    """A located address: ``area`` I, Q or M, ``size`` X, W or D, ``number`` (the byte of
    a bit, or the word's number) and ``bit`` (0-7, of an X only)."""

    area: str
    size: str
    number: int
    bit: int = 0

    def __str__(self) -> str:
        return f"%{self.area}{self.size}{self.number}" + (f".{self.bit}" if self.size == "X"
                                                          else "")


def parse_located(text: str) -> Located | str:
    """``text`` as a Located, or why it is none (the words of a refusal)."""
    m = _LOCATED.match(text.strip().upper())
    if m is None:
        return (f"'{text}' is no located address: expected %IX<byte>.<bit>, %QX<byte>.<bit>, "
                "%IW<n>, %QW<n>, %MW<n> or %MD<n> (e.g. %IX0.3, %QW2)")
    area, size, number, bit = m.group(1), m.group(2), int(m.group(3)), m.group(4)
    if size == "X" and (bit is None or int(bit) > 7):
        return f"'{text}': a bit address needs its bit, 0-7 (e.g. %{area}X{number}.0)"
    if size != "X" and bit is not None:
        return f"'{text}': only a bit address (%{area}X) has a '.bit'"
    return Located(area, size, number, int(bit or 0))
