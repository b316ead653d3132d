"""The log of the kernel's dm-log-writes target, read and replayed: the disk as it stood at
any point of the log (the power cut of tests/kernel_io/test_power_cut.py).

The format is the kernel's (Documentation/admin-guide/device-mapper/log-writes.rst and
drivers/md/dm-log-writes.c), all numbers little-endian:

* the super block, at byte 0: magic (u64, ``MAGIC``), version (u64, 1), the number of
  entries (u64), the sector size of the logged device (u32);
* from byte ``sectorsize`` on, the entries one after the other: a header of one sector
  (the device's sector written to (u64), the number of sectors (u64), flags (u64), the
  length of a mark's text (u64), then the text of a mark), followed by the data written,
  ``nr_sectors`` sectors (none for a discard, a flush or a mark). Sectors counted in the
  logged device's sector size.

The kernel logs a write only once it is on the disk, not in its cache: a plain write when
the next flush has completed (all such writes first, in the order they completed, then the
flush), a FUA write as soon as it completes. So every prefix of the log is a state the disk
can be in after a power cut: at a flush or FUA entry, everything acknowledged until then;
between two, the writes the flush was to make durable kept up to that point and the later
ones, not yet flushed, dropped. A mark is text a program inserted (``dmsetup message DEV 0
mark TEXT``) when it knew something had happened.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import BinaryIO

MAGIC = 0x6A736677736872
VERSION = 1
FLUSH, FUA, DISCARD, MARK, METADATA = 1, 2, 4, 8, 16
KNOWN_FLAGS = FLUSH | FUA | DISCARD | MARK | METADATA
_SUPER = struct.Struct("<QQQI")
_ENTRY = struct.Struct("<QQQQ")


class LogError(ValueError):
    """Not a dm-log-writes log, or a damaged one."""


@dataclass(frozen=True)
class Entry:
    """One entry of the log: a write (``sectors`` of data at ``sector``), a discard, a
    flush, a mark. ``data_at``: where the written data is in the log, bytes."""

    index: int
    sector: int
    sectors: int
    flags: int
    data_at: int
    mark: str | None = None

    @property
    def is_write(self) -> bool:
        """It changes the disk: data written or discarded."""
        return self.sectors > 0 and not self.flags & MARK

    @property
    def durable_point(self) -> bool:
        """A flush or FUA: what was acknowledged before is on the disk."""
        return bool(self.flags & (FLUSH | FUA))

    def kind(self) -> str:
        names = [n for bit, n in ((FLUSH, "flush"), (FUA, "fua"), (DISCARD, "discard"),
                                  (MARK, "mark"), (METADATA, "metadata")) if self.flags & bit]
        if self.sectors and not self.flags & (DISCARD | MARK):
            names.insert(0, "write")
        return "+".join(names)


@dataclass(frozen=True)
class Log:
    """A log: the sector size of the logged device and the entries."""

    sectorsize: int
    entries: list[Entry]


def read_log(f: BinaryIO) -> Log:
    """The entries of the log in ``f``; LogError if it is not one, or is cut short."""
    f.seek(0)
    head = f.read(_SUPER.size)
    if len(head) < _SUPER.size:
        raise LogError("too short for the super block")
    magic, version, count, sectorsize = _SUPER.unpack(head)
    if magic != MAGIC:
        raise LogError(f"bad magic {magic:#x}: not a dm-log-writes log")
    if version != VERSION:
        raise LogError(f"version {version}: only {VERSION} is known")
    if sectorsize < _ENTRY.size or sectorsize & (sectorsize - 1):
        raise LogError(f"sector size {sectorsize} is not a power of two of at least 32")
    entries = []
    at = sectorsize
    for index in range(count):
        f.seek(at)
        header = f.read(sectorsize)
        if len(header) < sectorsize:
            raise LogError(f"entry {index} of {count} is cut short at byte {at}")
        sector, sectors, flags, textlen = _ENTRY.unpack_from(header)
        if flags & ~KNOWN_FLAGS:
            raise LogError(f"entry {index} at byte {at}: unknown flags {flags:#x}")
        mark = None
        if flags & MARK:
            if textlen > sectorsize - _ENTRY.size:
                raise LogError(f"entry {index}: a mark of {textlen} bytes")
            mark = header[_ENTRY.size:_ENTRY.size + textlen].decode("utf-8", "replace")
        entries.append(Entry(index, sector, sectors, flags, at + sectorsize, mark))
        at += sectorsize
        if sectors and not flags & (DISCARD | MARK):
            at += sectors * sectorsize
    return Log(sectorsize, entries)


class Replay:
    """A disk image rebuilt from the log, one entry at a time: ``apply`` writes what the
    entry wrote (zeros for a discard) into ``image``, a copy of the disk as it was when
    logging began."""

    def __init__(self, log: Log, log_file: BinaryIO, image: BinaryIO) -> None:
        self.log = log
        self._log_file = log_file
        self._image = image
        self.applied = 0  # entries applied so far: the image is the disk after them

    def apply(self, entry: Entry) -> None:
        assert entry.index == self.applied, "entries are applied in order"
        self.applied += 1
        if not entry.is_write:
            return
        size = entry.sectors * self.log.sectorsize
        if entry.flags & DISCARD:
            data = bytes(size)
        else:
            self._log_file.seek(entry.data_at)
            data = self._log_file.read(size)
            if len(data) != size:
                raise LogError(f"entry {entry.index}: its data is cut short")
        self._image.seek(entry.sector * self.log.sectorsize)
        self._image.write(data)
        self._image.flush()

    def points(self) -> Iterator[Entry]:
        """Apply the entries one by one, yielding each once the image holds it."""
        for entry in self.log.entries[self.applied:]:
            self.apply(entry)
            yield entry
