"""The Modbus server's map as an HMI designer types it into a panel's tag editor
(``softplc modbus --map PLANT [--csv]``): one line per name, in table and address order.

Columns: ``ref`` (the 1-based 6-digit reference most tag editors take: 000001 the first
coil, 100001 the first discrete input, 300001 the first input register, 400001 the first
holding register), ``address`` (the table and the protocol address from 0, as on the wire:
what ``mbpoll -0`` and pymodbus take), ``type`` (BOOL, INT, UINT, DINT, UDINT, REAL, TIME),
``name``, ``description`` and ``unit`` (the I/O list's), ``access`` (R, or RW for a
writable name)."""

from __future__ import annotations

import csv
import io

from runtime.language.iolist import IOList
from runtime.language.modbusconf import TABLE_NAMES, reference
from runtime.language.model import ModbusDef, PlantDef

HEADER = ("ref", "address", "type", "name", "description", "unit", "access")
#: the tables in the order printed
ORDER = ("Q", "I", "IR", "HR")
#: a table as the address column names it
SHORT = {"Q": "coil", "I": "DI", "IR": "IR", "HR": "HR"}


def records(pdef: PlantDef, conf: ModbusDef) -> list[tuple[str, ...]]:
    """One tuple per mapped name, the columns of HEADER."""
    iolist = IOList(pdef)
    out: list[tuple[str, ...]] = []
    for pt in sorted(conf.points, key=lambda p: (ORDER.index(p.table), p.address)):
        m = iolist.meaning(pt.name)
        address = f"{SHORT[pt.table]} {pt.address}"
        if pt.words == 2:
            address += f"-{pt.address + 1}"
        unit = m.unit.symbol if m.unit is not None else "ms" if pt.type == "TIME" else ""
        out.append((reference(pt.table, pt.address), address, pt.type, pt.name,
                    m.description, unit, "RW" if pt.writable else "R"))
    return out


def table(pdef: PlantDef, conf: ModbusDef) -> list[str]:
    """The map as aligned columns, each table under a line naming it."""
    recs = records(pdef, conf)
    widths = [max(len(r[i]) for r in [HEADER, *recs]) for i in range(len(HEADER))]

    def line(r: tuple[str, ...]) -> str:
        return "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
    out = [line(HEADER)]
    shown = ""
    for r in recs:
        tbl = next(t for t, s in SHORT.items() if r[1].startswith(s + " "))
        if tbl != shown:
            shown = tbl
            out.append(f"# {TABLE_NAMES[tbl]}s")
        out.append(line(r))
    return out


def csv_text(pdef: PlantDef, conf: ModbusDef) -> str:
    """The map as CSV (a header line, comma-separated, UTF-8 text)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(HEADER)
    w.writerows(records(pdef, conf))
    return buf.getvalue()
