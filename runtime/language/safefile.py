"""Reading a file that someone else may have put in place: never blocking, never more than
a bound, never through a symbolic link unless asked.

Every file softplc reads at a start goes through ``read_bounded``: its charts, plant and
scripts (``yamlsrc.read_source``, links followed: a deployment may link its plant file),
its own state beside the retain file (the retain generations and the fault record: links
never followed, since softplc never makes one there) and the OPC UA server's trusted
certificates. What it guards against, each seen in an attack: a FIFO put in place (an
``open`` for reading waits for a writer, for ever: a start that hangs and ignores
SIGTERM), a link to ``/dev/zero`` (a read that never ends), a huge file, a device, and a
file of ``/proc`` that says it is empty and cannot be read (``/proc/self/mem``: EIO).
"""

from __future__ import annotations

import errno
import os
import stat

from runtime.errors import SoftplcError

#: what a file mode names, in the words of a refusal
_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISLNK, "a symbolic link"))
#: bytes asked of the kernel per read
_CHUNK = 65536


class UnfitFile(SoftplcError):
    """What a path names is not a regular file of at most the bound asked: a FIFO, a
    device, a directory, a symbolic link where none is followed, or a file larger than
    the bound. ``found`` says which ("a FIFO (named pipe)", "a file of 5242880 bytes")."""

    def __init__(self, path: str, found: str) -> None:
        super().__init__(f"{path}: {found}")
        self.path = path
        self.found = found


def kind_of(mode: int) -> str:
    """What ``st_mode`` names, as a refusal says it ("a FIFO (named pipe)")."""
    return next((what for test, what in _KINDS if test(mode)), "no regular file")


def read_bounded(path: str, limit: int, *, follow_links: bool = False) -> bytes:
    """The contents of the regular file ``path``, of at most ``limit`` bytes.

    Raises FileNotFoundError if nothing is there; UnfitFile if what is there is no regular
    file (or a symbolic link, unless ``follow_links``) or holds more than ``limit`` bytes;
    OSError (with its errno) if it cannot be opened or read.

    The status is looked at before opening (opening a device can have effects of its own),
    the file is opened non-blocking (a FIFO put in its place meanwhile cannot hang the
    open) and looked at again, and at most ``limit + 1`` bytes are read whatever its size
    said (a file that grows, a ``/proc`` file that says 0)."""
    look = os.stat if follow_links else os.lstat
    st = look(path)  # FileNotFoundError, ValueError for a NUL: the caller's paths have none
    if not stat.S_ISREG(st.st_mode):
        raise UnfitFile(path, kind_of(st.st_mode))
    flags = os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC | (0 if follow_links else os.O_NOFOLLOW)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        if exc.errno == errno.ELOOP and not follow_links:
            raise UnfitFile(path, "a symbolic link") from None
        raise
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnfitFile(path, kind_of(st.st_mode))
        if st.st_size > limit:
            raise UnfitFile(path, f"a file of {st.st_size} bytes")
        chunks: list[bytes] = []
        size = 0
        while True:
            chunk = os.read(fd, min(_CHUNK, limit + 1 - size))
            if not chunk:
                return b"".join(chunks)
            size += len(chunk)
            if size > limit:  # it grew since, or a /proc file that says 0
                raise UnfitFile(path, f"a file of at least {size} bytes")
            chunks.append(chunk)
    finally:
        os.close(fd)
