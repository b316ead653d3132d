"""Retained memory on disk: atomic, checksummed, generation-numbered, wear-conscious.

A save writes ``PATH.tmp``, fsyncs it, moves the current ``PATH`` to ``PATH.prev``, renames
the temporary file to ``PATH`` and fsyncs the directory. Whatever moment the power goes,
one of the three files holds a complete generation: loading takes the newest one whose
checksum is right and reports every file it had to pass over, so a torn or corrupt file
costs at most one generation and never stops the controller.

``RetainWriter`` does the saving in its own thread: the scan hands it a snapshot (a small
dict) and never waits for the disk.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any

log = logging.getLogger(__name__)

FORMAT = "softplc-retain/1"


@dataclass
class Loaded:
    """What ``RetainStore.load()`` found: the data of the newest good generation (empty
    if none), its generation number, and one line per file passed over."""

    data: dict[str, Any] = field(default_factory=dict)
    generation: int = 0
    saved_at: float | None = None  # wall-clock time of that save (time.time())
    source: str | None = None  # the file it came from
    problems: list[str] = field(default_factory=list)


def _digest(payload: dict[str, Any]) -> str:
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    return hashlib.sha256(text.encode()).hexdigest()


class RetainStore:
    """The retain file at ``path`` and its previous generation at ``path.prev``."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.prev = path + ".prev"
        self.tmp = path + ".tmp"
        self.generation = 0

    def load(self) -> Loaded:
        """The newest valid generation among the three files; never raises for bad files."""
        best = Loaded()
        for candidate in (self.path, self.prev, self.tmp):
            if not os.path.exists(candidate):
                continue
            try:
                with open(candidate, encoding="utf-8") as f:
                    doc = json.load(f)
                if not isinstance(doc, dict) or doc.get("format") != FORMAT:
                    raise ValueError("not a softplc retain file")
                payload = {k: doc[k] for k in ("format", "generation", "saved_at", "data")}
                if doc.get("sha256") != _digest(payload):
                    raise ValueError("checksum mismatch")
                gen = int(payload["generation"])
                if not isinstance(payload["data"], dict):
                    raise ValueError("no data mapping")
            except (OSError, ValueError, KeyError, TypeError) as exc:
                if candidate != self.tmp:  # a torn .tmp is the normal trace of a power cut
                    best.problems.append(f"{candidate}: {exc}; passed over")
                continue
            if gen > best.generation:
                best.data, best.generation = payload["data"], gen
                best.saved_at, best.source = float(payload["saved_at"]), candidate
        if best.source is not None and best.source != self.path:
            best.problems.append(f"restored generation {best.generation} from {best.source}")
        self.generation = max(self.generation, best.generation)
        return best

    def save(self, data: dict[str, Any]) -> int:
        """Write ``data`` as the next generation, atomically. Returns its number.
        Raises OSError (disk full, read-only file system): the caller logs and goes on."""
        self.generation += 1
        payload = {"format": FORMAT, "generation": self.generation, "saved_at": time.time(),
                   "data": data}
        doc = {**payload, "sha256": _digest(payload)}
        directory = os.path.dirname(os.path.abspath(self.path))
        os.makedirs(directory, exist_ok=True)
        fd = os.open(self.tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o640)
        try:
            os.write(fd, json.dumps(doc, ensure_ascii=False, indent=1).encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        if os.path.exists(self.path):
            os.replace(self.path, self.prev)
        os.replace(self.tmp, self.path)
        dfd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)
        return self.generation


class RetainWriter:
    """A thread that saves the latest submitted snapshot; older unsaved ones are dropped."""

    def __init__(self, store: RetainStore) -> None:
        self.store = store
        self._cond = threading.Condition()
        self._pending: dict[str, Any] | None = None
        self._busy = False
        self._stop = False
        self.saves = 0
        self.last_error: str | None = None
        self._thread = threading.Thread(target=self._run, name="softplc-retain", daemon=True)
        self._thread.start()

    def submit(self, data: dict[str, Any]) -> None:
        """Called by the scan thread: never blocks on the disk."""
        with self._cond:
            self._pending = data
            self._cond.notify()

    def flush(self, timeout: float = 5.0) -> bool:
        """Wait until everything submitted is on disk (shutdown). False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._pending is None and not self._busy,
                                       timeout)

    def close(self, timeout: float = 5.0) -> None:
        self.flush(timeout)
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._stop)
                if self._pending is None:
                    return
                data, self._pending = self._pending, None
                self._busy = True
            try:
                self.store.save(data)
                self.saves += 1
                if self.last_error is not None:
                    log.warning("retain file %s written again", self.store.path)
                self.last_error = None
            except OSError as exc:
                if self.last_error is None:
                    log.error("retain file %s not written: %s", self.store.path, exc)
                self.last_error = str(exc)
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()
