"""Disk images, loop devices and mounts for the power-cut test, by the kernel's own calls
(ioctls on /dev/loop-control and the loop device, mount(2), umount2(2)): the test mounts
hundreds of disk images, and a process started for each step took most of its time under
emulation; so did copying the whole image for each, hence the sparse copies (only the
blocks that hold data are written, the rest stay holes)."""

from __future__ import annotations

import ctypes
import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# linux/loop.h
LOOP_SET_FD = 0x4C00
LOOP_CLR_FD = 0x4C01
LOOP_CTL_GET_FREE = 0x4C82

MS_RDONLY = 1
#: the block size the images are scanned in, bytes
BLOCK = 4096

_libc = ctypes.CDLL(None, use_errno=True)


def sparse_copy(src: Path, dst: Path) -> None:
    """``dst`` becomes a copy of ``src`` in which only the blocks of ``src`` that are not
    all zeros are written (the others are holes, read as zeros)."""
    zero = bytes(BLOCK)
    with open(src, "rb") as f, open(dst, "wb") as g:
        size = os.fstat(f.fileno()).st_size
        at = 0
        while at < size:
            block = f.read(BLOCK)
            if block != zero[:len(block)]:
                g.seek(at)
                g.write(block)
            at += len(block)
        g.truncate(size)


def copy_data(src: Path, dst: Path) -> None:
    """``dst`` becomes a copy of ``src``, holes kept: only the data extents are copied
    (SEEK_DATA, SEEK_HOLE, copy_file_range)."""
    with open(src, "rb") as f, open(dst, "wb") as g:
        size = os.fstat(f.fileno()).st_size
        g.truncate(size)
        at = 0
        while at < size:
            try:
                start = os.lseek(f.fileno(), at, os.SEEK_DATA)
            except OSError:  # ENXIO: no data after ``at``
                break
            end = os.lseek(f.fileno(), start, os.SEEK_HOLE)
            left, pos = end - start, start
            while left:
                n = os.copy_file_range(f.fileno(), g.fileno(), left, pos, pos)
                if n <= 0:
                    raise OSError(f"copy_file_range made no progress at {pos}")
                left -= n
                pos += n
            at = end


def _check(result: int, what: str) -> None:
    if result != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


@contextmanager
def loop_device(image: Path) -> Iterator[str]:
    """``image`` as a block device, /dev/loopN, detached afterwards."""
    ctl = os.open("/dev/loop-control", os.O_RDWR | os.O_CLOEXEC)
    try:
        number = fcntl.ioctl(ctl, LOOP_CTL_GET_FREE)
    finally:
        os.close(ctl)
    dev = f"/dev/loop{number}"
    fd = os.open(dev, os.O_RDWR | os.O_CLOEXEC)
    try:
        backing = os.open(image, os.O_RDWR | os.O_CLOEXEC)
        try:
            fcntl.ioctl(fd, LOOP_SET_FD, backing)
        finally:
            os.close(backing)
        try:
            yield dev
        finally:
            fcntl.ioctl(fd, LOOP_CLR_FD)
    finally:
        os.close(fd)


@contextmanager
def mounted(dev: str, where: Path, *, readonly: bool = False,
            fstype: str = "ext4") -> Iterator[None]:
    """``dev`` mounted at ``where``. Read-only too, the kernel recovers an ext4 journal
    (on a device it may write: a loop device of a file)."""
    flags = MS_RDONLY if readonly else 0
    _check(_libc.mount(dev.encode(), str(where).encode(), fstype.encode(), flags, None),
           f"mount {dev} on {where}")
    try:
        yield
    finally:
        _check(_libc.umount2(str(where).encode(), 0), f"umount {where}")
