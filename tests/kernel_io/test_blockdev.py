"""The image copies of the power-cut test (tests/kernel_io/blockdev.py): same bytes, only
the data written. Runs anywhere (the loop devices and mounts run in the guest)."""

from __future__ import annotations

import os
from pathlib import Path

from tests.kernel_io.blockdev import BLOCK, copy_data, sparse_copy


def allocated(path: Path) -> int:
    """Bytes the file system gave the file."""
    return os.stat(path).st_blocks * 512


def test_a_sparse_copy_writes_only_the_blocks_with_data(tmp_path: Path) -> None:
    src, sparse, copy = tmp_path / "src", tmp_path / "sparse", tmp_path / "copy"
    content = bytearray(64 * BLOCK)
    content[5 * BLOCK:5 * BLOCK + 3] = b"abc"
    content[-1] = 7
    src.write_bytes(bytes(content))  # every block written, zeros too
    sparse_copy(src, sparse)
    assert sparse.read_bytes() == src.read_bytes()
    assert allocated(sparse) <= 8 * BLOCK < allocated(src)
    copy_data(sparse, copy)
    assert copy.read_bytes() == src.read_bytes()
    assert allocated(copy) <= 8 * BLOCK


def test_copy_data_of_a_file_without_holes_is_whole(tmp_path: Path) -> None:
    src, copy = tmp_path / "src", tmp_path / "copy"
    src.write_bytes(os.urandom(3 * BLOCK + 5))
    copy.write_bytes(b"left over from before" * 1000)
    copy_data(src, copy)
    assert copy.read_bytes() == src.read_bytes()
