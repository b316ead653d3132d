"""What an installed softplc unit can see and use: the paths its sandbox hides
(``ProtectHome=yes``, ``PrivateTmp=yes``), the places it may write (``ProtectSystem=
strict``), what its user may read, and what ``ExecStart=`` runs.

``softplc install-service`` asks these before it writes anything, so that a unit that
could never start (``status=203/EXEC``: a venv made from a Python under /root, a clone's
``.venv`` under /tmp) or never read its certificate is refused with one line naming the
path and the directive that hides it, instead of being installed into a restart loop.
"""

from __future__ import annotations

import grp
import os
import pwd
import stat
from collections.abc import Iterable

#: directories the units hide, and the directive that hides each
HIDDEN = (("/home", "ProtectHome=yes"), ("/root", "ProtectHome=yes"),
          ("/run/user", "ProtectHome=yes"), ("/tmp", "PrivateTmp=yes"),
          ("/var/tmp", "PrivateTmp=yes"))


def below(path: str, directory: str) -> bool:
    """Whether ``path`` is ``directory`` or inside it (both absolute, normalised)."""
    return path == directory or path.startswith(directory.rstrip("/") + "/")


def hidden_by(path: str, follow: bool = True) -> str | None:
    """The directive that hides ``path`` (as written, or once its links are followed unless
    ``follow`` is false) from the service; None if the service sees it."""
    for p in (os.path.abspath(path), *([os.path.realpath(path)] if follow else [])):
        for directory, directive in HIDDEN:
            if below(p, directory):
                return directive
    return None


def exec_chain(softplc: str) -> list[tuple[str, str]]:
    """(what, path) of every file ``ExecStart={softplc} ...`` needs: the program, the
    Python of its ``#!`` line and that Python's real file (a venv's ``python`` is a link
    to the Python that made it), and the installed ``runtime`` package (an editable
    install points into its source tree)."""
    out = [("the program", softplc)]
    try:
        with open(softplc, "rb") as f:
            first = f.readline(4096)
    except OSError:
        first = b""
    if first.startswith(b"#!"):
        interpreter = first[2:].decode("utf-8", "replace").split()[0]
        out.append((f"the Python of {softplc}", interpreter))
        real = os.path.realpath(interpreter)
        if real != interpreter:
            out.append((f"the Python of {softplc} ({interpreter} is a link to it)", real))
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out.append(("the softplc package it imports", os.path.realpath(package)))
    return out


def service_identity(user: str, groups: Iterable[str]) -> tuple[int, set[int]]:
    """The uid of ``user`` (-1 if it does not exist yet: then only "others" permissions
    count) and the gids it has or will have (its own group and ``groups`` that exist)."""
    try:
        pw = pwd.getpwnam(user)
        uid, gids = pw.pw_uid, set(os.getgrouplist(user, pw.pw_gid))
    except KeyError:
        uid, gids = -1, set()
    for name in (user, *groups):
        try:
            gids.add(grp.getgrnam(name).gr_gid)
        except KeyError:
            pass
    return uid, gids


def _may(st: os.stat_result, uid: int, gids: set[int], bits: int) -> bool:
    mode = st.st_mode
    if st.st_uid == uid:
        have = (mode >> 6) & 7
    elif st.st_gid in gids:
        have = (mode >> 3) & 7
    else:
        have = mode & 7
    return have & bits == bits


def unreadable(path: str, uid: int, gids: set[int], execute: bool = False) -> str | None:
    """Why the user ``uid`` (groups ``gids``) cannot read ``path`` (and run it, with
    ``execute``; a directory: list it): the first directory on the way it may not search,
    or the file itself; None if it can. Links are followed; ACLs are not read."""
    real = os.path.realpath(path)
    try:
        st = os.stat(real)
    except OSError as exc:
        return f"{real}: {exc.strerror}"
    parts = real.strip("/").split("/")
    for i in range(len(parts)):
        directory = "/" + "/".join(parts[:i])
        if not _may(os.stat(directory), uid, gids, 1):
            return f"{directory} is mode {stat.S_IMODE(os.stat(directory).st_mode):04o}, " \
                   "not searchable by it"
    search = stat.S_ISDIR(st.st_mode)
    if not _may(st, uid, gids, 4 | (1 if execute or search else 0)):
        need = "readable and searchable" if search else \
            "readable and executable" if execute else "readable"
        return f"{real} is mode {stat.S_IMODE(st.st_mode):04o} {_owner(st)}, not {need} by it"
    return None


def _owner(st: os.stat_result) -> str:
    try:
        user = pwd.getpwuid(st.st_uid).pw_name
    except KeyError:
        user = str(st.st_uid)
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    return f"{user}:{group}"
