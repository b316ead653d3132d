"""``${RUNTIME_DIR}`` in a plant file's paths: the user's own directory for the console
socket and other files of a controller started by hand.

``${RUNTIME_DIR}`` is, first found:

1. ``$RUNTIME_DIRECTORY``: set by systemd for a unit with ``RuntimeDirectory=`` (the
   installed service: /run/softplc);
2. ``$XDG_RUNTIME_DIR/softplc`` when ``$XDG_RUNTIME_DIR`` is an absolute path to a directory
   of this user (a login session: /run/user/UID);
3. ``${TMPDIR:-/tmp}/softplc-UID`` otherwise.

This module only names the directory; ``runtime.controller.paths`` creates it (0700) and
checks it before the controller uses it. Nothing else is expanded: any other ``${`` in a path
is an error, so that a misspelt placeholder never becomes a directory named ``${...}``.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Mapping

from runtime.errors import Loc, SourceError

PLACEHOLDER = "${RUNTIME_DIR}"


def runtime_dir(env: Mapping[str, str] | None = None, uid: int | None = None) -> str:
    """The directory ``${RUNTIME_DIR}`` stands for (nothing is created or checked here
    but whether ``$XDG_RUNTIME_DIR`` is this user's)."""
    env = os.environ if env is None else env
    uid = os.geteuid() if uid is None else uid
    systemd = env.get("RUNTIME_DIRECTORY", "").split(":")[0]
    if os.path.isabs(systemd):
        return os.path.normpath(systemd)
    xdg = env.get("XDG_RUNTIME_DIR", "")
    if os.path.isabs(xdg):
        try:
            st = os.lstat(xdg)
        except OSError:
            st = None
        # su keeps the caller's XDG_RUNTIME_DIR: only a directory of this user counts
        if st is not None and stat.S_ISDIR(st.st_mode) and st.st_uid == uid:
            return os.path.join(os.path.normpath(xdg), "softplc")
    tmp = env.get("TMPDIR", "")
    return os.path.join(os.path.normpath(tmp) if os.path.isabs(tmp) else "/tmp",
                        f"softplc-{uid}")


def expand(path: str, loc: Loc, env: Mapping[str, str] | None = None) -> str:
    """``path`` with ``${RUNTIME_DIR}`` replaced; SourceError at ``loc`` for any other
    ``${...}``."""
    if "${" not in path:
        return path
    rest = path.replace(PLACEHOLDER, "")
    if "${" in rest:
        raise SourceError(loc, f"unknown placeholder in '{path}': the only one is "
                               f"{PLACEHOLDER}")
    return path.replace(PLACEHOLDER, runtime_dir(env))
