"""One controller per plant: an ``flock`` held for the controller's life, which also
records the sockets it binds, so that its next run knows which files it made.

The lock file is ``runtime.language.runtimedir.locate(pdef).lock``
(``${RUNTIME_DIR}/NAME-HASH.lock``). It holds text lines::

    pid 4242
    plant /etc/softplc/press1/plant.yaml
    socket /run/softplc/press1/console.sock 2049 118273

The kernel releases the lock however the process ends (SIGKILL included). The file itself
is never removed: removing a lock file races with the next process taking it.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os

from runtime.errors import SoftplcError
from runtime.language.runtimedir import Whereabouts

log = logging.getLogger(__name__)

#: a lock file longer than this is not one of ours: its contents are ignored, bytes
MAX_BYTES = 65536


class PlantLocked(SoftplcError):
    """The plant's controller already runs (its lock is held), or the lock cannot be taken
    (a lock file that is not a regular file of ours, a directory we may not write)."""


def _read(fd: int) -> dict[str, list[str]]:
    """The lines of an open lock file, by their first word."""
    out: dict[str, list[str]] = {}
    try:
        raw = os.pread(fd, MAX_BYTES, 0)
    except OSError:
        return out
    for line in raw.decode("utf-8", "replace").splitlines():
        key, _, value = line.partition(" ")
        out.setdefault(key, []).append(value)
    return out


def _holder(fd: int) -> tuple[int, str]:
    """(PID, plant file) the lock file says (-1, "" if it does not)."""
    found = _read(fd)
    pids, plants = found.get("pid", []), found.get("plant", [])
    return (int(pids[0]) if pids and pids[0].isdigit() else -1,
            plants[0] if plants else "")


def holder(path: str) -> tuple[int, str] | None:
    """(PID, plant file) of the process that holds the lock at ``path``; None if nobody
    does (or the file is not there). Only reads: usable on another user's runtime
    directory."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                return None
            return _holder(fd)
        return None
    finally:
        os.close(fd)


class PlantLock:
    """The lock of the plant ``where`` (``acquire`` once, held until the process ends)."""

    def __init__(self, where: Whereabouts) -> None:
        self.where = where
        self.path = where.lock
        self._fd: int | None = None
        #: sockets recorded by the previous holder: path -> (device, inode)
        self.previous: dict[str, tuple[int, int]] = {}
        self._sockets: dict[str, tuple[int, int]] = {}

    def refusal(self, pid: int, plant: str) -> PlantLocked:
        who = f"PID {pid}" if pid > 0 else "a process"
        return PlantLocked(f"plant {self.where.name} is already running: {who} "
                           f"({plant or self.where.home}, lock {self.path})")

    def check(self) -> None:
        """PlantLocked if the controller of this plant runs (before any directory check:
        the lock of an installed plant is found even by a user who may not write there)."""
        found = holder(self.path)
        if found is not None:
            raise self.refusal(*found)

    def acquire(self) -> None:
        """Take the lock, or raise PlantLocked at once (never waits). Remembers the sockets
        the previous holder recorded, then records this process."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC,
                         0o600)
        except OSError as exc:
            raise PlantLocked(f"cannot take the lock of plant {self.where.name}: "
                              f"{self.path}: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            found = _holder(fd)
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise self.refusal(*found) from None
            raise PlantLocked(f"cannot take the lock of plant {self.where.name}: "
                              f"{self.path}: {exc.strerror}") from None
        st = os.fstat(fd)
        if st.st_uid != os.geteuid():
            os.close(fd)
            raise PlantLocked(f"{self.path} belongs to uid {st.st_uid}, not to you (uid "
                              f"{os.geteuid()}): remove it")
        self._fd = fd
        for value in _read(fd).get("socket", []):
            try:
                path, dev, ino = value.rsplit(" ", 2)
                self.previous[path] = (int(dev), int(ino))
            except ValueError:
                continue
        self._write()

    @property
    def held(self) -> bool:
        return self._fd is not None

    def made_before(self, path: str, dev: int, ino: int) -> bool:
        """Whether the socket at ``path`` (``dev``, ``ino``) was bound by an earlier run of
        this plant (so it is this plant's to replace)."""
        return self.previous.get(path) == (dev, ino)

    def record_socket(self, path: str, dev: int, ino: int) -> None:
        """A socket this process bound: written to the lock file at once (a SIGKILL right
        after leaves it recorded)."""
        self._sockets[path] = (dev, ino)
        self._write()

    def forget_socket(self, path: str) -> None:
        self._sockets.pop(path, None)
        self._write()

    def _write(self) -> None:
        if self._fd is None:
            return
        lines = [f"pid {os.getpid()}", f"plant {self.where.plant}"]
        # the previous holder's sockets stay recorded until this run has replaced them
        # (a start that fails before binding them must not forget them)
        for path, (dev, ino) in {**self.previous, **self._sockets}.items():
            lines.append(f"socket {path} {dev} {ino}")
        data = ("\n".join(lines) + "\n").encode()
        try:
            os.ftruncate(self._fd, 0)
            os.pwrite(self._fd, data, 0)
        except OSError as exc:  # the lock is held all the same; only the record is lost
            log.warning("lock %s not written: %s", self.path, exc.strerror)
