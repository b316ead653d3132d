"""Directories the controller writes into are its own: created private, checked before use.

A file the controller creates (retained data, its fault record, the console socket) must
not land in a directory another local user controls: that user could pre-create it, or a
symbolic link in its place, before the controller starts (the classic attack on /tmp).

- ``${RUNTIME_DIR}`` (runtime.language.runtimedir) is created with mode 0700 if missing,
  then must be a real directory (not a symbolic link) owned by this user and open to nobody
  else: no access for others, and for group at most what systemd's RuntimeDirectoryMode=
  0750 gives when systemd made it ($RUNTIME_DIRECTORY).
- Any other directory holding such a file must be owned by this user or root and not
  writable by every user; a missing one may not be created inside a directory writable by
  every user (another user could create it first); no symbolic link on the way may belong to
  another user.

Otherwise the controller refuses to start, with one line naming the directory and the fix.
"""

from __future__ import annotations

import logging
import os
import socket
import stat
from collections.abc import Iterable

from runtime.errors import SoftplcError
from runtime.language.model import PlantDef
from runtime.language.runtimedir import PLACEHOLDER, runtime_dir

log = logging.getLogger(__name__)

#: the permission bits a runtime directory may have for group and others
PRIVATE = 0o077  # none: the directory we create
SYSTEMD = 0o027  # group read/search allowed: systemd's RuntimeDirectoryMode=0750


class PathError(SoftplcError):
    """A directory the controller would write into is not safely its own."""


def plant_files(pdef: PlantDef) -> list[str]:
    """The files the controller creates for this plant: retained data (and the fault
    record beside it), the console sockets."""
    files = [pdef.retain_path] if pdef.retain_path else []
    files += [c.address for c in pdef.consoles if c.kind == "socket"]
    return files


def prepare(files: Iterable[str]) -> None:
    """Create ``${RUNTIME_DIR}`` if a file is below it, and check the directory of every
    file; PathError with one line otherwise."""
    rdir = runtime_dir()
    for path in files:
        directory = os.path.dirname(os.path.abspath(path))
        if directory == rdir or directory.startswith(rdir + os.sep):
            ensure_private_dir(rdir, SYSTEMD if os.environ.get("RUNTIME_DIRECTORY")
                               else PRIVATE)
        check_dir(directory, path)


def ensure_private_dir(path: str, forbidden: int = PRIVATE) -> None:
    """Create ``path`` with mode 0700 if missing; then it must be a directory of ours, not
    a symbolic link, with none of the ``forbidden`` permission bits."""
    try:
        os.mkdir(path, 0o700)
        log.info("created %s (mode 0700)", path)
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


def unix_listener(path: str) -> socket.socket:
    """A listening-ready AF_UNIX stream socket bound at ``path`` (the console's and the
    feed's): its directory made if missing, a socket file left by a previous run
    replaced, the socket 0660 (its owner and group: the directory's mode decides who
    reaches it). OSError if it cannot be bound."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if os.path.exists(path):
        os.unlink(path)  # left by a previous run
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        srv.bind(path)
        os.chmod(path, 0o660)
    except OSError:
        srv.close()
        raise
    return srv
