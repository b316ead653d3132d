"""``softplc run --trace FILE``: one JSON line per cycle, off the scan thread."""

from __future__ import annotations

import collections
import json
import logging
import threading
from typing import IO, Any

from runtime.engine.plant import Plant
from runtime.engine.trace import trace_columns

log = logging.getLogger(__name__)


class TraceWriter:
    """``run --trace FILE``: one JSON line per cycle, built in the scan thread (an opt-in
    cost of a few µs per instance) and written by a thread of its own."""

    def __init__(self, plant: Plant, out: IO[str]) -> None:
        self.columns = trace_columns(plant)
        self.out = out
        self.plant = plant
        self._rows: collections.deque[dict[str, Any]] = collections.deque(maxlen=100_000)
        self._wake = threading.Event()
        self._stop = False
        self.dropped = 0
        self.failed = False  # the file could not be written (a reader gone, a full disk)
        self._thread = threading.Thread(target=self._run, name="softplc-trace", daemon=True)
        self._thread.start()

    def __call__(self, n: int) -> None:
        if self.failed:
            return
        row: dict[str, Any] = {"cycle": n - 1, "t_ms": self.plant.last_up // 1_000_000}
        for key, get in self.columns:
            row[key] = get()
        if len(self._rows) == self._rows.maxlen:
            self.dropped += 1
        self._rows.append(row)
        self._wake.set()

    def _run(self) -> None:
        while True:
            self._wake.wait(0.2)
            self._wake.clear()
            # read before draining: the stop is set after the last row was queued, so every
            # row is written (read after, a row queued and the stop set between the drain
            # and the test would be lost, were threads switched there)
            stop = self._stop
            try:
                while self._rows:
                    self.out.write(json.dumps(self._rows.popleft(), ensure_ascii=False,
                                              separators=(",", ":")) + "\n")
                if stop:
                    self.out.flush()
                    return
            except OSError as exc:  # EPIPE (SIGPIPE is ignored), ENOSPC: the plant runs on
                self.failed = True
                self._rows.clear()
                log.error("trace stopped: %s", exc)
                try:
                    self.out.close()  # closed even if its last flush fails again
                except OSError:
                    pass
                return

    def close(self) -> None:
        self._stop = True
        self._wake.set()
        self._thread.join(timeout=5.0)
        if self.dropped:
            log.warning("trace: %d rows dropped (the disk was too slow)", self.dropped)
