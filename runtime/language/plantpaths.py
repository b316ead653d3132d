"""The paths a plant file names (its charts, the retain file, the console's serial port and
socket, the OPC UA feed socket, certificates and key): one check for all, at load, and
one place where a relative path is read (``resolve``: from the plant file's directory,
whatever the working directory of the command that loads it).

A path is text, with ``${RUNTIME_DIR}`` expanded (``runtimedir.expand``), that the system
can take: not empty, no NUL character (YAML's ``"\\0"``: Python refuses it with a
traceback, the kernel would cut the path there), encodable as a file name, at most
``PATH_MAX_BYTES`` long with no name longer than ``NAME_MAX_BYTES``; a Unix socket's path
at most ``SOCKET_PATH_MAX_BYTES`` (Linux's ``sun_path``), counted after the expansion.
Each is refused with one ``FILE:LINE:COL`` error at the value. ``path_value`` does not look
at the file system (what a path names is checked where it is used); ``missing`` says
whether something of the expected kind is there, for the files a plant names that must
exist when it is loaded (the OPC UA certificate, key and trusted directories).
"""

from __future__ import annotations

import os
import stat
from typing import Any

from runtime.errors import Loc, SourceError
from runtime.language.grafcetfile import expect_type
from runtime.language.runtimedir import PLACEHOLDER, expand, runtime_dir

#: the longest path the kernel takes (PATH_MAX, 4096 bytes with its NUL), bytes
PATH_MAX_BYTES = 4095
#: the longest name of one directory entry (NAME_MAX), bytes
NAME_MAX_BYTES = 255
#: the longest Unix socket path: ``sun_path`` holds 108 bytes with its NUL, bytes
SOCKET_PATH_MAX_BYTES = 107


def path_value(value: Any, loc: Loc, what: str, *, socket: bool = False) -> str:
    """``value`` (a plant file's value at ``loc``) as the path of ``what`` ("plc retain",
    "monitor socket"), ``${RUNTIME_DIR}`` expanded; SourceError at ``loc`` if it is no
    path the system takes (see the module's docstring). ``socket``: a Unix socket's."""
    text = str(expect_type(value, loc, str, f"a path for {what}"))
    path = expand(text, loc)
    problem = path_problem(path, socket=socket)
    if problem is not None:
        if PLACEHOLDER in text:
            problem += f" ({PLACEHOLDER} is {runtime_dir(plant=loc.file)})"
        raise SourceError(loc, f"{what}: {problem}")
    return path


def path_problem(path: str, *, socket: bool = False) -> str | None:
    """Why ``path`` (expanded) is no path the system takes, None if it is one."""
    if not path.strip():
        return "expected a path, found an empty text"
    if "\0" in path:
        return ("expected a path, found one holding the character NUL (U+0000, \\0 in YAML): "
                "no file name can hold it")
    try:
        raw = os.fsencode(path)
    except UnicodeEncodeError as exc:
        return (f"expected a path, found the character U+{ord(path[exc.start]):04X}, which "
                "no file name can hold")
    if len(raw) > PATH_MAX_BYTES:
        return f"expected a path of at most {PATH_MAX_BYTES} bytes, found {len(raw)} bytes"
    longest = max(raw.split(b"/"), key=len)
    if len(longest) > NAME_MAX_BYTES:
        return (f"expected names of at most {NAME_MAX_BYTES} bytes between the '/', found "
                f"one of {len(longest)} bytes")
    if socket and len(raw) > SOCKET_PATH_MAX_BYTES:
        return (f"a Unix socket path holds at most {SOCKET_PATH_MAX_BYTES} bytes, found "
                f"{len(raw)} bytes in '{path}': choose a shorter directory or name")
    return None


def resolve(base: str, path: str) -> str:
    """``path`` (expanded) as the plant file ``base`` names it: an absolute path as it is,
    a relative one from the plant file's directory (every path of a plant file)."""
    return path if os.path.isabs(path) else os.path.normpath(
        os.path.join(os.path.dirname(os.path.abspath(base)), path))


def plant_path(base: str, value: Any, loc: Loc, what: str) -> str:
    """``path_value`` resolved against the plant file ``base`` (``resolve``)."""
    return resolve(base, path_value(value, loc, what))


def missing(path: str, *, directory: bool = False) -> str | None:
    """Why nothing of the kind expected is at ``path`` (a file, or a ``directory``): "no
    file PATH", "PATH is a directory, expected a file"...; None if it is there, and None
    when this user may not look (a directory closed to them: whoever reads it says)."""
    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return f"no {'directory' if directory else 'file'} {path}"
    except OSError:
        return None
    if directory and not stat.S_ISDIR(mode):
        return f"{path} is not a directory"
    if not directory and stat.S_ISDIR(mode):
        return f"{path} is a directory, expected a file"
    return None
