"""Directories the controller writes into are its own: created private, checked before use.

A file the controller creates (retained data, its fault record, the console socket) must
not land in a directory another local user controls: that user could pre-create it, or a
symbolic link in its place, before the controller starts (the classic attack on /tmp).

- ``${RUNTIME_DIR}`` (runtime.language.runtimedir) is created with mode 0700 if missing,
  then must be a real directory (not a symbolic link) owned by this user and open to nobody
  else: no access for others, and for group at most what systemd's RuntimeDirectoryMode=
  0750 gives when systemd made it ($RUNTIME_DIRECTORY, or an installed plant's
  /run/softplc/NAME). A plant run by hand has its own below the user's
  (``$XDG_RUNTIME_DIR/softplc/NAME-HASH``): that parent is made and checked the same way.
- Any other directory holding such a file must be owned by this user or root and not
  writable by every user; a missing one may not be created inside a directory writable by
  every user (another user could create it first); no symbolic link on the way may belong to
  another user.

Otherwise the controller refuses to start, with one line naming the directory and the fix.

A Unix socket (the console's, the feed's) is bound only where nothing is, or where an
earlier run of this plant left its own socket (``SocketLedger``, recorded in the plant's
lock file); at the stop it is removed only if it is still the one this process bound.
"""

from __future__ import annotations

import logging
import os
import socket
import stat
import struct
from collections.abc import Iterable
from typing import TYPE_CHECKING

from runtime.errors import SoftplcError
from runtime.language.model import PlantDef
from runtime.language.runtimedir import PLACEHOLDER, locate, managed_by_systemd, runtime_dir

if TYPE_CHECKING:
    from runtime.controller.plantlock import PlantLock

log = logging.getLogger(__name__)

#: the permission bits a runtime directory may have for group and others
PRIVATE = 0o077  # none: the directory we create
SYSTEMD = 0o027  # group read/search allowed: systemd's RuntimeDirectoryMode=0750


class PathError(SoftplcError):
    """A directory the controller would write into is not safely its own."""


def plant_files(pdef: PlantDef) -> list[str]:
    """The files the controller creates for this plant: its lock, retained data (and the
    fault record beside it), the console sockets, the feed socket."""
    where = locate(pdef)
    files = [where.lock] + ([pdef.retain_path] if pdef.retain_path else [])
    files += [c.address for c in pdef.consoles if c.kind == "socket"]
    return files + ([where.feed] if where.feed else [])


def prepare(files: Iterable[str], rdir: str | None = None) -> None:
    """Create the runtime directory ``rdir`` (``${RUNTIME_DIR}``) if a file is below it,
    and check the directory of every file; PathError with one line otherwise."""
    rdir = runtime_dir() if rdir is None else rdir
    for path in files:
        directory = os.path.dirname(os.path.abspath(path))
        if directory == rdir or directory.startswith(rdir + os.sep):
            if managed_by_systemd(rdir):
                ensure_private_dir(rdir, SYSTEMD)
            else:
                if os.path.dirname(rdir) == runtime_dir():  # a plant's own, below the user's
                    ensure_private_dir(os.path.dirname(rdir))
                    ensure_private_dir(rdir, said=logging.DEBUG)  # each plant's first run
                else:
                    ensure_private_dir(rdir)
        check_dir(directory, path)


def ensure_private_dir(path: str, forbidden: int = PRIVATE, said: int = logging.INFO) -> None:
    """Create ``path`` with mode 0700 if missing (logged at level ``said``); then it must be
    a directory of ours, not a symbolic link, with none of the ``forbidden`` permission
    bits."""
    try:
        os.mkdir(path, 0o700)
        log.log(said, "created %s (mode 0700)", path)
    except FileExistsError:
        pass
    except OSError as exc:
        raise PathError(f"cannot create {path}: {exc.strerror}") from None
    st = os.lstat(path)
    me = os.geteuid()
    if stat.S_ISLNK(st.st_mode):
        raise PathError(f"{path} is a symbolic link (uid {st.st_uid}), not a directory: "
                        f"remove it, it is not safe to follow")
    if not stat.S_ISDIR(st.st_mode):
        raise PathError(f"{path} is not a directory: remove it")
    if st.st_uid != me:
        raise PathError(f"{path} belongs to uid {st.st_uid}, not to you (uid {me}): another "
                        f"user may have created it; remove it or set XDG_RUNTIME_DIR")
    if stat.S_IMODE(st.st_mode) & forbidden:
        raise PathError(f"{path} has mode {stat.S_IMODE(st.st_mode):04o}, open to other "
                        f"users: chmod 700 {path}")


def check_dir(directory: str, for_file: str) -> None:
    """The directory that will hold ``for_file`` (or its nearest existing parent, where the
    controller would create it) belongs to this user or root and is not writable by every
    user; no symbolic link on the way belongs to another user."""
    me = os.geteuid()
    hint = (f"put {os.path.basename(for_file)} in a directory of yours, e.g. "
            f"{PLACEHOLDER}/{os.path.basename(for_file)}")
    existing = directory
    while not os.path.lexists(existing):
        existing = os.path.dirname(existing)
    part = "/"
    for name in existing.strip("/").split("/"):
        part = os.path.join(part, name)
        st = os.lstat(part)
        if stat.S_ISLNK(st.st_mode) and st.st_uid not in (0, me):
            raise PathError(f"{for_file}: {part} is a symbolic link of uid {st.st_uid}: "
                            f"{hint}")
    try:
        st = os.stat(existing)
    except OSError as exc:
        raise PathError(f"{for_file}: {existing}: {exc.strerror}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise PathError(f"{for_file}: {existing} is not a directory")
    if st.st_uid not in (0, me):
        raise PathError(f"{for_file}: {existing} belongs to uid {st.st_uid}, not to you "
                        f"(uid {me}) or root: {hint}")
    if st.st_mode & stat.S_IWOTH:
        what = "would be created in" if existing != directory else "is in"
        raise PathError(f"{for_file} {what} {existing}, writable by every user: {hint}")


class SocketLedger:
    """The Unix sockets this process bound (path -> device, inode), and the plant lock that
    records them for the next run (``runtime.controller.plantlock``): a process unlinks
    only what it made."""

    def __init__(self) -> None:
        self.lock: PlantLock | None = None
        self.bound: dict[str, tuple[int, int]] = {}


#: this process's sockets: one process runs one plant at most
LEDGER = SocketLedger()

_KINDS = ((stat.S_ISREG, "a regular file"), (stat.S_ISDIR, "a directory"),
          (stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISCHR, "a device"), (stat.S_ISBLK, "a device"))


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (for "... is not a socket")."""
    return next((k for test, k in _KINDS if test(mode)), "not a socket")


def _listener_pid(path: str) -> int | None:
    """The PID of the process listening on the socket at ``path`` (0 if it listens but
    its PID is unknown); None if nobody listens there."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        probe.settimeout(0.5)
        try:
            probe.connect(path)
        except (ConnectionRefusedError, FileNotFoundError):
            return None
        except OSError:  # a full backlog, a timeout: somebody is there
            return 0
        cred = probe.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
        return int(struct.unpack("3i", cred)[0])


def _clear(path: str, what: str, ledger: SocketLedger) -> None:
    """Make room for the socket at ``path``: nothing there, or a socket an earlier run of
    this plant bound (removed); PathError for anything else, left alone."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise PathError(f"{path} exists and is not a socket ({file_kind(st.st_mode)}): left "
                        f"alone; give the {what} socket another path")
    pid = _listener_pid(path)
    if pid is not None:
        who = f" (PID {pid})" if pid else ""
        raise PathError(f"{path}: another process listens there{who}: left alone; stop it "
                        f"or give the {what} socket another path")
    mine = ledger.bound.get(path) == (st.st_dev, st.st_ino) or (
        ledger.lock is not None and ledger.lock.made_before(path, st.st_dev, st.st_ino))
    if not mine:
        raise PathError(f"{path}: a socket that was not made by this plant: left alone; "
                        f"remove it if nothing uses it")
    os.unlink(path)  # left by an earlier run of this plant (killed, or its directory kept)
    log.info("replaced %s, left by an earlier run of this plant", path)


def unix_listener(path: str, what: str = "console",
                  ledger: SocketLedger = LEDGER) -> socket.socket:
    """A listening-ready AF_UNIX stream socket bound at ``path`` (the console's and the
    feed's, ``what`` says which): its directory made if missing, a socket this plant left
    in an earlier run replaced (and nothing else: PathError), the socket 0660 (its owner
    and group: the directory's mode decides who reaches it), recorded as made by this
    plant. OSError if it cannot be bound."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    _clear(path, what, ledger)
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        srv.bind(path)
        os.chmod(path, 0o660)
        st = os.lstat(path)
    except OSError:
        srv.close()
        raise
    ledger.bound[path] = (st.st_dev, st.st_ino)
    if ledger.lock is not None:
        ledger.lock.record_socket(path, st.st_dev, st.st_ino)
    return srv


def remove_socket(path: str, ledger: SocketLedger = LEDGER) -> None:
    """Remove the socket at ``path`` if it is still the one this process bound (another
    controller may have bound the path since: its socket is left alone)."""
    ident = ledger.bound.pop(path, None)
    try:
        st = os.lstat(path)
    except OSError:
        st = None
    if ident is not None and st is not None and (st.st_dev, st.st_ino) == ident:
        try:
            os.unlink(path)
        except OSError as exc:
            log.warning("%s not removed: %s", path, exc.strerror)
    if ledger.lock is not None:
        ledger.lock.forget_socket(path)
