"""The dm-log-writes reader and replay of the power-cut test (tests/kernel_io/logwrites.py),
on logs written here in the kernel's format: runs anywhere (the kernel's own log is read in
the guest, test_power_cut.py, which also checks that replaying all of it gives the disk)."""

from __future__ import annotations

import io
import struct

import pytest

from tests.kernel_io.logwrites import (
    DISCARD,
    FLUSH,
    FUA,
    MAGIC,
    MARK,
    METADATA,
    LogError,
    Replay,
    read_log,
)

SECTOR = 512


def entry(sector: int, sectors: int, flags: int, data: bytes = b"", mark: str = "") -> bytes:
    text = mark.encode()
    header = struct.pack("<QQQQ", sector, sectors, flags, len(text)) + text
    return header.ljust(SECTOR, b"\0") + data


def log_of(*entries: bytes, count: int | None = None, magic: int = MAGIC,
           version: int = 1) -> io.BytesIO:
    n = len(entries) if count is None else count
    head = struct.pack("<QQQI", magic, version, n, SECTOR).ljust(SECTOR, b"\0")
    return io.BytesIO(head + b"".join(entries))


def sample() -> io.BytesIO:
    return log_of(
        entry(2, 1, 0, b"a" * SECTOR),                      # a write, not yet flushed
        entry(0, 0, FLUSH),                                 # ... now on the disk
        entry(0, 0, MARK, mark="saved 1"),
        entry(1, 2, FUA | METADATA, b"b" * 2 * SECTOR),     # a FUA write, two sectors
        entry(2, 1, DISCARD),                               # its data: none in the log
        entry(3, 1, FLUSH | FUA, b"c" * SECTOR),            # a commit block
    )


def test_the_entries_are_read_as_the_kernel_writes_them() -> None:
    log = read_log(sample())
    assert log.sectorsize == SECTOR
    assert [e.kind() for e in log.entries] == [
        "write", "flush", "mark", "write+fua+metadata", "discard", "write+flush+fua"]
    assert [e.mark for e in log.entries] == [None, None, "saved 1", None, None, None]
    assert [e.durable_point for e in log.entries] == [False, True, False, True, False, True]
    assert [e.is_write for e in log.entries] == [True, False, False, True, True, True]
    # headers at 512, data after them; a flush, a mark and a discard carry none
    assert [e.data_at for e in log.entries] == [1024, 2048, 2560, 3072, 4608, 5120]


def test_the_disk_is_rebuilt_one_entry_at_a_time() -> None:
    f = sample()
    log = read_log(f)
    image = io.BytesIO(b"0" * 4 * SECTOR)
    replay = Replay(log, f, image)
    seen = [image.getvalue()[::SECTOR].decode() for _ in replay.points()]
    assert seen == ["00a0", "00a0", "00a0", "0bb0", "0b\x000", "0b\x00c"]
    assert replay.applied == 6


@pytest.mark.parametrize("log, words", [
    (log_of(magic=0x1234), "bad magic"),
    (log_of(version=2), "version 2"),
    (log_of(entry(0, 0, FLUSH), count=2), "entry 1 of 2 is cut short"),
    (log_of(entry(0, 0, 1 << 9)), "unknown flags 0x200"),
    (io.BytesIO(b"short"), "too short"),
])
def test_what_is_not_a_whole_log_is_refused(log: io.BytesIO, words: str) -> None:
    with pytest.raises(LogError, match=words):
        read_log(log)


def test_a_write_whose_data_is_cut_short_is_refused_at_replay() -> None:
    f = log_of(entry(0, 4, 0, b"x" * SECTOR))  # four sectors announced, one there
    log = read_log(f)
    with pytest.raises(LogError, match="entry 0: its data is cut short"):
        list(Replay(log, f, io.BytesIO(bytes(8 * SECTOR))).points())
