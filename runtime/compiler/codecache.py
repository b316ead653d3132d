"""Compiled generated code kept on disk, so that ``compile``, ``simulate``, ``run`` and a
reload of an unchanged chart skip CPython's ``compile()`` (a 1000-step chart: 0.2-0.4 s).

An entry is the ``marshal`` of a code object that passed :func:`runtime.compiler.guard.
checked_code`, named by the SHA-256 of what it was compiled from: the generated source, its
filename, the compiler's version (:data:`COMPILER_VERSION` and a digest of the compiler's
modules) and the Python that compiled it (version and bytecode magic number). A changed
chart, compiler or Python makes another name: an entry is never looked up for another text.

A marshalled code object is not data: crafted bytecode can do anything in the process that
loads it (the guard checks operations, names and constants, not every operand), so an entry
is loaded only when all of these hold (docs/architecture.md, "Generated code"):

- the directory is a real directory (no link), owned by the process's user, with no
  permission for group or others (created 0700; one that is not so is not used);
- the entry and the key are regular files (opened without following a link), owned by the
  user, writable by no one else, one link each, under :data:`MAX_ENTRY` bytes;
- the entry starts with the HMAC-SHA256 of its name and its code under the cache's key
  (32 random bytes, a 0600 file of the directory): a file written without the key, or
  altered, is refused (a warning line) and compiled again;
- the code, unmarshalled, passes :func:`runtime.compiler.guard.check_code` again.

The directory: ``$SOFTPLC_CODE_CACHE`` when set (``off`` or empty: no cache), else
``$XDG_CACHE_HOME/softplc/code``, else ``~/.cache/softplc/code``. Any failure of the cache
(a directory that cannot be made, a full disk, a refused entry) means compiling as without
it: the cache changes how long a load takes, never what it loads.
"""

from __future__ import annotations

import hashlib
import hmac
import importlib.util
import logging
import marshal
import os
import secrets
import stat
import sys
from collections.abc import Collection
from types import CodeType

from runtime.compiler.guard import GeneratedCodeRefused, check_code, checked_code

log = logging.getLogger(__name__)

#: raised whenever what the compiler emits or how the guard checks it changes in a way the
#: generated source does not show (the source itself is part of every entry's name)
COMPILER_VERSION = 1
#: the largest entry read, bytes (a 4000-step chart's code is about 3 MB)
MAX_ENTRY = 64 * 1024 * 1024
#: the bytes of the HMAC at the start of an entry, and of the key
DIGEST = 32
ENV = "SOFTPLC_CODE_CACHE"
#: sources shorter than this, characters, are compiled without the cache (a small chart,
#: a plant's cycle, an expression: compiled in less time than an entry takes to check)
MIN_SOURCE = 32 * 1024


def _compiler_digest() -> str:
    """SHA-256 of the compiler's own modules (this package's ``.py`` files): any change to
    the compiler or its guard names other entries."""
    h = hashlib.sha256()
    here = os.path.dirname(os.path.abspath(__file__))
    try:
        for name in sorted(os.listdir(here)):
            if name.endswith(".py"):
                with open(os.path.join(here, name), "rb") as f:
                    h.update(name.encode() + b"\0" + f.read() + b"\0")
    except OSError:
        return "unknown"
    return h.hexdigest()[:16]


#: what an entry's name depends on beyond its source: the compiler, the Python
VERSION_TAG = (f"softplc-code {COMPILER_VERSION} {_compiler_digest()} "
               f"{sys.implementation.cache_tag} {importlib.util.MAGIC_NUMBER.hex()} "
               f"{sys.version}")


def cache_dir() -> str | None:
    """The cache's directory as configured (module docstring), or None: no cache."""
    configured = os.environ.get(ENV)
    if configured is not None:
        return None if configured.strip() in ("", "off") else configured
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    if not os.path.isabs(base):
        return None
    return os.path.join(base, "softplc", "code")


def entry_name(source: str, filename: str) -> str:
    """The name of the entry of ``source`` compiled as ``filename``."""
    h = hashlib.sha256(VERSION_TAG.encode())
    h.update(b"\0" + filename.encode("utf-8", "surrogatepass") + b"\0")
    h.update(source.encode("utf-8", "surrogatepass"))
    return h.hexdigest() + ".code"


def _private_file(fd: int, limit: int) -> bool:
    """The open file is a regular file of this user, one link, written by no one else,
    at most ``limit`` bytes."""
    st = os.fstat(fd)
    return (stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid() and st.st_nlink == 1
            and not st.st_mode & 0o022 and st.st_size <= limit)


def _read_private(name: str, limit: int, dir_fd: int) -> bytes | None:
    """The bytes of the file ``name`` of the directory ``dir_fd`` if it passes
    :func:`_private_file`, else None."""
    try:
        fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC,
                     dir_fd=dir_fd)
    except OSError:
        return None
    try:
        if not _private_file(fd, limit):
            return None
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        return b"".join(chunks) if size <= limit else None
    finally:
        os.close(fd)


class CodeCache:
    """The cache in ``directory`` (made 0700 if missing), held open for its life (every
    file of it opened relative to the directory checked: no path is looked up twice);
    ``usable`` false when the directory or its key is not private to this user (then
    every lookup misses and nothing is written). A context manager: ``close`` at its end."""

    def __init__(self, directory: str) -> None:
        self.directory = directory
        self.hits = 0
        self.misses = 0
        self.refused = 0
        self._fd = -1
        self._key = self._open()
        self.usable = self._key is not None

    def __enter__(self) -> CodeCache:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        self.usable = False

    def _open(self) -> bytes | None:
        try:
            os.makedirs(self.directory, mode=0o700, exist_ok=True)
            self._fd = os.open(self.directory, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW
                               | os.O_CLOEXEC)
        except OSError as e:
            log.debug("code cache %s not used: %s", self.directory, e)
            return None
        st = os.fstat(self._fd)
        if st.st_uid != os.geteuid() or st.st_mode & 0o077:
            log.warning("code cache %s not used: not a directory private to this user "
                        "(owner and mode 0700 expected)", self.directory)
            return None
        key = _read_private("key", DIGEST, self._fd)
        if key is None:  # written whole, then linked in: another process sees all or none
            tmp = f".key-{secrets.token_hex(8)}"
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW
                             | os.O_CLOEXEC, 0o600, dir_fd=self._fd)
                with os.fdopen(fd, "wb") as f:
                    f.write(secrets.token_bytes(DIGEST))
                try:
                    os.link(tmp, "key", src_dir_fd=self._fd, dst_dir_fd=self._fd)
                finally:
                    os.unlink(tmp, dir_fd=self._fd)
            except OSError as e:  # FileExistsError: another process made it first
                log.debug("code cache %s: no key made: %s", self.directory, e)
            key = _read_private("key", DIGEST, self._fd)
        if key is None or len(key) != DIGEST:
            log.warning("code cache %s not used: its key is not a private file of %d bytes",
                        self.directory, DIGEST)
            return None
        return key

    def _mac(self, name: str, blob: bytes) -> bytes:
        assert self._key is not None
        return hmac.new(self._key, name.encode() + b"\0" + blob, hashlib.sha256).digest()

    def load(self, source: str, filename: str, names: Collection[str]) -> CodeType | None:
        """The cached code of ``source``, checked again (GeneratedCodeRefused if it fails
        the guard), or None: a miss, or an entry refused (a warning; the next
        :meth:`store` replaces it)."""
        if not self.usable:
            return None
        name = entry_name(source, filename)
        data = _read_private(name, MAX_ENTRY + DIGEST, self._fd)
        if data is None:
            self.misses += 1
            return None
        mac, blob = data[:DIGEST], data[DIGEST:]
        if not hmac.compare_digest(mac, self._mac(name, blob)):
            self.refused += 1
            log.warning("code cache %s: entry %s refused (not written with this cache's "
                        "key); compiling again", self.directory, name)
            return None
        try:
            code = marshal.loads(blob)  # noqa: S302 - authenticated above
        except (ValueError, EOFError, TypeError):
            code = None
        if not isinstance(code, CodeType):
            self.refused += 1
            log.warning("code cache %s: entry %s refused (no code object); compiling again",
                        self.directory, name)
            return None
        check_code(code, filename, names)  # the code that runs is checked where it runs
        self.hits += 1
        return code

    def store(self, source: str, filename: str, code: CodeType) -> None:
        """Keep ``code`` (compiled from ``source`` and checked) under its name; a failure
        to write is logged at debug level and otherwise ignored."""
        if not self.usable:
            return
        name = entry_name(source, filename)
        blob = marshal.dumps(code)
        if len(blob) > MAX_ENTRY:
            return
        tmp = f".new-{secrets.token_hex(8)}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW
                         | os.O_CLOEXEC, 0o600, dir_fd=self._fd)
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(self._mac(name, blob) + blob)
                os.replace(tmp, name, src_dir_fd=self._fd, dst_dir_fd=self._fd)
            except BaseException:
                os.unlink(tmp, dir_fd=self._fd)
                raise
        except OSError as e:
            log.debug("code cache %s: %s not written: %s", self.directory, name, e)


def cached_code(source: str, filename: str, names: Collection[str]) -> CodeType:
    """``checked_code(source, filename, names)``, through the cache when one is configured
    (:func:`cache_dir`)."""
    directory = cache_dir()
    if directory is None or len(source) < MIN_SOURCE:
        return checked_code(source, filename, names)
    with CodeCache(directory) as cache:
        try:
            code = cache.load(source, filename, names)
        except GeneratedCodeRefused:  # refused as the guard refuses it once compiled below
            code = None
        if code is not None:
            return code
        code = checked_code(source, filename, names)
        cache.store(source, filename, code)
        return code


__all__ = ["COMPILER_VERSION", "ENV", "MIN_SOURCE", "VERSION_TAG", "CodeCache", "cache_dir",
           "cached_code", "entry_name"]
